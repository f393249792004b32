#pragma once
// [view]: the live viewer's settings (the viewer itself: outputs/live_view.hpp).
#include <string>

namespace pp5 {
class ConfigSchema;
}

namespace pp5::host {

// How a slice through the volume looks: the MPR images a run writes
// (run.mpr_*) and the viewer's slices (outputs/slices.hpp).
struct SliceLook {
  int longSide = 512;      // pixels on the slice's longer side; the other keeps the proportions
  double window = 255.0;   // grey levels mapped from black to white ...
  double level = 127.5;    // ... centred here
};

// [view]
struct ViewSettings {
  std::string listen;        // "[ADDR:]PORT"; "" = no viewer (`run --view` sets it)
  std::string token;         // "" = a random one when the address is not loopback
  bool serve = false;        // keep the final volume interactive after the input ends (`run --serve`)
  double imageHz = 30.0;     // at most this many 3D images per second to the browsers
  int jpegQuality = 85;
  double bmodeHz = 15.0;     // B-mode frames per second to the browsers
  double sliceHz = 2.0;      // the volume fetched for the slices at most this often
  int sliceSize = 384;       // the slices' longer side, pixels
  double dragStepScale = 2.0;  // the ray step times this while the user drags
  int dragPixelStride = 2;     // and a ray for every n-th pixel along x and y (the finest a drag uses)
  double dragRateHz = 15.0;    // a drag's stride coarsens until its views come this often (0: fixed)
  std::string webRoot;       // the page's folder; "" = the one built in
};
void registerOptions(ConfigSchema& schema, ViewSettings& s);
// InputError for settings that cannot work together: view.serve without
// view.listen, a view.drag_pixel_stride that does not divide 8.
void checkViewSettings(const ViewSettings& s);

}  // namespace pp5::host
