#pragma once
// [render]: the view and the ray lattice, shared by the GP's sampler, the
// PP's cache and the pipeline that drives them.
#include <cstdint>
#include <string>
#include <vector>

#include "core/camera.hpp"
#include "core/enum_names.hpp"
#include "core/grid.hpp"

namespace pp5 {

class ConfigSchema;

// How a ray's samples combine into a pixel (the pixel processor composites).
enum class CompositeMode : std::uint8_t { Over, Additive, Mip };
// MIP and additive composite grey values, shown through render.value_window;
// "over" composites classified, shaded colour.
inline bool compositesGreyValues(CompositeMode m) { return m != CompositeMode::Over; }

struct RenderSettings {
  int width = 512;
  int height = 512;
  Projection projection = Projection::Perspective;
  double fovDeg = 30.0;                    // perspective: vertical field of view
  // The eye orbits the grid's centre: azimuth about +z from +x, elevation
  // above the xy plane; its distance is `distance` times the radius of the
  // grid's bounding sphere (perspective), and an orthographic view frames
  // that sphere.
  double azimuthDeg = -120.0;
  double elevationDeg = 35.0;
  double distance = 3.2;
  // The global lattice: ray r samples at t0(r) + k * step, k < max_samples,
  // t0(r) where it enters the grid's box. 0 = half the smallest voxel spacing.
  double stepMm = 0.0;
  int maxSamples = 512;
  // The transfer function's alpha is the opacity of this length of ray; each
  // sample's is corrected to the step: 1 - (1 - alpha)^(step / unit).
  double opacityUnitMm = 1.0;
  // Composition modes, the first one live.
  std::vector<CompositeMode> compositing = {CompositeMode::Over, CompositeMode::Mip};
  int threads = 0;  // 0 = every core
  // Set while the user drags the view (not options): the step times this
  // (a coarser, faster lattice), rays for every pixelStride-th pixel along x
  // and y only (SampleLattice), and the look-at point moved by this many mm
  // along the camera's right and up.
  double stepScale = 1.0;
  int pixelStride = 1;
  double panMm[2] = {0.0, 0.0};
  // MIP and additive: the grey levels shown as black and white.
  glm::dvec2 valueWindow{0.0, 255.0};

  double step(const Grid& g) const;
};

void registerOptions(ConfigSchema& schema, RenderSettings& s);

// The camera of `s` looking at grid `g` (image size, projection, orbit).
Camera makeCamera(const RenderSettings& s, const Grid& g);

template <>
struct EnumNames<CompositeMode> {
  static constexpr std::string_view key = "render.compositing";
  static constexpr std::array<std::pair<CompositeMode, std::string_view>, 3> names{{
      {CompositeMode::Over, "over"},
      {CompositeMode::Additive, "additive"},
      {CompositeMode::Mip, "mip"}}};
};

}  // namespace pp5
