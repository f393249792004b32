#pragma once
// Slices through a reconstructed volume for people to read (MPR): at display
// resolution, trilinear, through a window and level, at any position along
// the plane's normal and tilted (oblique), with the scan coverage shown on
// them. What the live viewer shows and what `run` writes (mpr_*.png).
#include <cstdint>
#include <string>
#include <vector>

#include "formats/volume_io.hpp"
#include "host/view_settings.hpp"

namespace pp5::host {

class Coverage;

// The three planes: axial (normal z, image x right and y up), coronal
// (normal y, x right, z up) and sagittal (normal x, y right, z up).
enum class SliceAxis { Axial = 0, Coronal = 1, Sagittal = 2 };

struct SlicePlane {
  SliceAxis axis = SliceAxis::Axial;
  double position = 0.5;  // along the normal, 0..1 of the grid's extent
  double tiltDeg = 0.0;   // rotation about the image's horizontal axis (oblique)
};


struct SliceImage {
  int width = 0, height = 0;
  std::vector<std::uint8_t> rgb;  // width * height * 3, top row first
};

// InputError for a window <= 0 or a long side outside 8..8192. Points outside
// the grid are black. With `coverage`, voxels no frame has swept are tinted.
SliceImage slice(const Volume& v, const SlicePlane& plane, const SliceLook& look, const Coverage* coverage = nullptr);

std::string_view sliceName(SliceAxis a);  // "axial" | "coronal" | "sagittal"

// The three planes through the centre (position 0.5, no tilt) as
// `<stem>_axial.png`, `<stem>_coronal.png` and `<stem>_sagittal.png`.
// Returns the paths written.
std::vector<std::string> writeMpr(const Volume& v, const SliceLook& look, const std::string& stem);

}  // namespace pp5::host
