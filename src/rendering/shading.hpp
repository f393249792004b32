#pragma once
// Shading: each voxel's colour and opacity from the reconstructed grey values,
// written premultiplied into the ShadeBuffer that the ray sampler reads.
//
//  - Classification by table lookup (TransferFunction, [render.tf]): continuous
//    in the grey value, never a threshold.
//  - `value` mode: the tables' colour and opacity as they are.
//  - `grey` mode: the voxel's own grey level as its colour (the image value),
//    the table's opacity, unlit.
//  - `phong` mode: the tables' colour lit by ambient + diffuse |N.L| and a white
//    specular highlight, N from central differences of the grey values in mm
//    (one-sided at the grid's faces). Lighting is two-sided, because an echo
//    boundary has no outside: the normal is turned towards the light.
//  - Optionally (Levoy 1988) the opacity is scaled by a ramp of the gradient
//    magnitude, so that boundaries show and homogeneous tissue fades.
//
// A voxel's result depends only on its own value and those of its six face
// neighbours, computed from absolute voxel indices, so re-shading a region
// gives the same bits as the same voxels of a full re-shade, for any thread
// count and any split into boxes.
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "core/camera.hpp"
#include "core/transfer_function.hpp"
#include "formats/volume_io.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/shade_buffer.hpp"
#include "core/enum_names.hpp"

namespace pp5 {
class ConfigSchema;
}

namespace pp5::gp {

enum class ShadeMode { Phong, Value, Grey };
enum class LightKind { Viewer, Direction };

// [render.shading]. The transfer function is separate ([render.tf]).
struct ShadeSettings {
  ShadeMode mode = ShadeMode::Phong;
  double ambient = 0.3;
  double diffuse = 0.7;
  double specular = 0.25;
  double shininess = 20.0;
  LightKind light = LightKind::Viewer;
  // World direction from the light towards the scene (light = "direction").
  glm::dvec3 lightDirection{1.0, 1.0, -1.0};
  // Below this gradient magnitude (grey levels per mm) a normal means little:
  // the voxel's lighting fades from Phong to ambient + diffuse (see shade()).
  double flatGradient = 1.0;
  // Levoy's opacity modulation: opacity times clamp((|grad| - low) / width, 0, 1),
  // |grad| in grey levels per mm.
  bool gradientOpacity = false;
  double gradientOpacityLow = 2.0;
  double gradientOpacityWidth = 30.0;
  // 0 = every core; the result does not depend on it. Not an option of its
  // own: the pipeline passes render.threads.
  int threads = 0;
  // Not an option: set while the live composition is MIP or additive, which
  // composite grey values. Each voxel is then (v, v, v, v), v its grey level
  // (0..255, rounded): no transfer function, no light.
  bool greyValues = false;

};

// InputError for a value the schema would refuse (settings built in code
// are held to the same ranges as files).
void checkShadeSettings(const ShadeSettings& s);
void registerOptions(ConfigSchema& schema, ShadeSettings& s);

// Re-shades every voxel of `box` (clipped to the grid) from the grey values
// `values` (F32, U16 or U8; values are clamped to 0..255 first, NaN to 0).
// The gradients read the six face neighbours of each voxel, so the caller must
// have made the values current in `box` grown by one voxel. Where the gradient
// magnitude g is below s.flatGradient, the light is blended by w = g /
// flatGradient: intensity = ambient + diffuse * (1 - w + w |N.L|) + w * specular
// term, so a flat region is lit as ambient + diffuse, without a highlight, and
// nothing jumps where g crosses the threshold.
// InputError for settings that registerOptions' schema would refuse, and for a
// zero light direction; InvariantError when the grids of `values` and `out`
// differ, or (phong) when the camera has no view direction.
void shade(const Volume& values, const TransferFunction& tf, const ShadeSettings& s, const Camera& view,
           const Box3& box, ShadeBuffer& out);

// Re-shades every voxel of `boxes` (disjoint; each clipped to the grid), as
// one parallel pass over all of them, with the lighting set up once: prefer
// it to a loop of single-box calls. `changed` (optional): the linear index
// of every voxel whose shade this call changed is appended, in ascending
// order (what a ray sample can have changed from: rendering/change_tracker.hpp).
void shade(const Volume& values, const TransferFunction& tf, const ShadeSettings& s, const Camera& view,
           std::span<const Box3> boxes, ShadeBuffer& out, std::vector<std::int64_t>* changed = nullptr);

// Re-shades every voxel whose shading the changed values in `dirty` can change:
// the dirty bricks and the face neighbours of their voxels (shadingBoxes()).
void shade(const Volume& values, const TransferFunction& tf, const ShadeSettings& s, const Camera& view,
           const DirtyRegion& dirty, ShadeBuffer& out);

// The voxels that shade(..., dirty, ...) re-shades, as disjoint boxes: every
// voxel of a dirty brick, and every voxel with a face neighbour in one (the
// gradient's reach). Adjacent boxes are merged, so a run of dirty bricks is a
// few large boxes rather than many small ones.
std::vector<Box3> shadingBoxes(const DirtyRegion& dirty);

}  // namespace pp5::gp

namespace pp5 {

template <>
struct EnumNames<gp::ShadeMode> {
  static constexpr std::string_view key = "render.shading.mode";
  static constexpr std::array<std::pair<gp::ShadeMode, std::string_view>, 3> names{{
      {gp::ShadeMode::Phong, "phong"},
      {gp::ShadeMode::Value, "value"},
      {gp::ShadeMode::Grey, "grey"}}};
};

template <>
struct EnumNames<gp::LightKind> {
  static constexpr std::string_view key = "render.shading.light";
  static constexpr std::array<std::pair<gp::LightKind, std::string_view>, 2> names{{
      {gp::LightKind::Viewer, "viewer"},
      {gp::LightKind::Direction, "direction"}}};
};

}  // namespace pp5
