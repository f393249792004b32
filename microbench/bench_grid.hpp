#pragma once
// The grid the shading and sampling benchmarks run on: 256 voxels a side at
// 0.8 mm, centred on the origin.
#include "core/grid.hpp"

namespace pp5::bench {

inline Grid benchGrid() {
  Grid g;
  g.dims = Index3(256);
  g.spacing = Vec3(0.8);
  g.origin = Vec3(-0.5 * 255 * 0.8);
  return g;
}

}  // namespace pp5::bench
