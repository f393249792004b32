#pragma once
// Small geometry helpers shared by the ray-sampling tests.
#include <random>

#include <glm/glm.hpp>

#include "core/camera.hpp"
#include "core/grid.hpp"

namespace pp5::test {

inline Vec3 gridCentre(const Grid& g) { return 0.5 * (g.minCorner() + g.maxCorner()); }

// A direction drawn uniformly from the unit sphere.
inline Vec3 randomUnit(std::mt19937& rng) {
  std::normal_distribution<double> n;
  Vec3 v;
  do v = Vec3(n(rng), n(rng), n(rng));
  while (glm::length(v) < 1e-3);
  return glm::normalize(v);
}

// How randomCamera draws a view: an eye inside the grid lies in
// [eyeLo, eyeLo + eyeSpan] of each side (as fractions); the field of view lies in
// [fovMinDeg, fovMinDeg + fovSpanDeg]; the orthographic height in
// [1, 1 + orthoSpan] x the grid's half-diagonal.
struct CameraDraw {
  double eyeLo = 0.1, eyeSpan = 0.8;
  double fovMinDeg = 20.0, fovSpanDeg = 70.0;
  double orthoSpan = 1.5;
};

// A random view of the grid, looking near its centre from outside (or, with
// eyeInside, from within its box), with a random up vector.
inline Camera randomCamera(std::mt19937& rng, const Grid& g, Projection proj, bool eyeInside, int w, int h,
                           const CameraDraw& d = {}) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Camera c;
  c.projection = proj;
  c.width = w;
  c.height = h;
  const Vec3 centre = gridCentre(g), ext = g.maxCorner() - g.minCorner();
  const double radius = 0.5 * glm::length(ext);
  c.target = centre + (Vec3(u(rng), u(rng), u(rng)) - 0.5) * ext * 0.5;
  if (eyeInside) {
    c.eye = g.minCorner() +
            Vec3(d.eyeLo + d.eyeSpan * u(rng), d.eyeLo + d.eyeSpan * u(rng), d.eyeLo + d.eyeSpan * u(rng)) * ext;
    if (glm::length(c.target - c.eye) < 1.0) c.target = c.eye + randomUnit(rng) * 10.0;
  } else {
    c.eye = centre + randomUnit(rng) * radius * (1.3 + 2.0 * u(rng));
  }
  c.up = randomUnit(rng);
  if (glm::length(glm::cross(glm::normalize(c.target - c.eye), c.up)) < 0.2) c.up = Vec3(0, 0, 1);
  if (glm::length(glm::cross(glm::normalize(c.target - c.eye), c.up)) < 0.2) c.up = Vec3(0, 1, 0);
  c.fovYDeg = d.fovMinDeg + d.fovSpanDeg * u(rng);
  c.orthoHeightMm = radius * (1.0 + d.orthoSpan * u(rng));
  return c;
}

}  // namespace pp5::test
