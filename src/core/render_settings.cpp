#include "core/render_settings.hpp"
#include "core/threads.hpp"

#include "core/enum_names.hpp"

#include <algorithm>
#include <cmath>

#include "core/config.hpp"
#include "core/error.hpp"

namespace pp5 {

double RenderSettings::step(const Grid& g) const {
  return stepScale * (stepMm > 0.0 ? stepMm : 0.5 * std::min(g.spacing.x, std::min(g.spacing.y, g.spacing.z)));
}

void registerOptions(ConfigSchema& c, RenderSettings& s) {
  c.section("render", "The rendered view: image size, projection, the camera's orbit and the ray lattice.");
  c.option("render.width", &s.width, 512, 16, 8192, "Image width in pixels.");
  c.option("render.height", &s.height, 512, 16, 8192, "Image height in pixels.");
  enumOption(c, "render.projection", &s.projection, Projection::Perspective,
           "`perspective` (the 1990 paper's choice, for depth perception) or `orthographic`.");
  c.option("render.fov_deg", &s.fovDeg, 30.0, 1.0, 150.0, "Perspective: vertical field of view, degrees.");
  c.option("render.azimuth_deg", &s.azimuthDeg, -120.0, -360.0, 360.0,
           "Where the eye is, about +z from +x around the grid's centre, degrees.");
  c.option("render.elevation_deg", &s.elevationDeg, 35.0, -89.0, 89.0, "The eye's height above the xy plane, degrees.");
  c.option("render.distance", &s.distance, 3.2, 1.05, 100.0,
           "Eye distance from the grid's centre, in radii of the grid's bounding sphere (perspective).");
  c.option("render.step_mm", &s.stepMm, 0.0, 0.0, 100.0,
           "Distance between samples along a ray, mm; 0 = half the smallest voxel spacing.");
  c.option("render.max_samples", &s.maxSamples, 512, 1, 65535, "At most this many samples per ray.");
  c.option("render.opacity_unit_mm", &s.opacityUnitMm, 1.0, 0.001, 1000.0,
           "Length of ray whose opacity the transfer function gives; each sample's opacity is corrected to the "
           "step as 1 - (1 - alpha)^(step / unit).");
  enumListOption(c, "render.compositing", &s.compositing, {CompositeMode::Over, CompositeMode::Mip},
            "Composition modes to render, the first one live: `over` (front to back, Levoy), `additive` "
            "(the sum of the grey values along the ray times the step, times render.cache.additive_scale), `mip` "
            "(maximum intensity projection: the largest grey value along the ray). `mip` and `additive` "
            "composite grey values, not the transfer function's colours, shown through render.value_window.");
  c.option("render.value_window", &s.valueWindow, {0.0, 255.0}, 0.0, 1e6,
           "MIP and additive: the grey levels shown as black and as white ([0, 255]: the grey value itself).");
  c.option("render.threads", &s.threads, 0, 0, kMaxThreads,
           "Threads for shading, sampling and compositing; 0 = every core. Under mpirun, parallel.threads replaces it.");
}

Camera makeCamera(const RenderSettings& s, const Grid& g) {
  const Vec3 lo = g.voxelToWorld(Vec3(-0.5)), hi = g.voxelToWorld(Vec3(g.dims) - Vec3(0.5));
  const Vec3 centre = 0.5 * (lo + hi);
  const double radius = 0.5 * glm::length(hi - lo);
  const double az = glm::radians(s.azimuthDeg), el = glm::radians(s.elevationDeg);
  const Vec3 dir(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
  Camera c;
  c.projection = checkedEnum(s.projection);
  c.width = s.width;
  c.height = s.height;
  c.fovYDeg = s.fovDeg;
  c.target = centre;
  c.eye = centre + dir * (radius * s.distance);
  c.up = Vec3(0, 0, 1);
  c.orthoHeightMm = 2.0 * radius;
  if (s.panMm[0] != 0.0 || s.panMm[1] != 0.0) {
    const Vec3 shift = s.panMm[0] * c.right() + s.panMm[1] * c.trueUp();
    c.target += shift;
    c.eye += shift;
  }
  return c;
}

}  // namespace pp5
