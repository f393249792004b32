#pragma once
// Small geometry helpers shared by the ray-sampling tests.
#include <random>

#include <glm/glm.hpp>

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

}  // namespace pp5::test
