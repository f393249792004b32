#include "rendering/stencil.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <tuple>

#include "core/error.hpp"

namespace pp5::gp {

std::vector<WorldBox> stencilBoxes(const Grid& g, std::span<const Box3> changed, int extraVoxels) {
  PP5_CHECK_GE(extraVoxels, 0);
  std::vector<WorldBox> out;
  out.reserve(changed.size());
  const Vec3 top = Vec3(g.dims - Index3(1));
  for (const Box3& b : changed) {
    const Box3 v = b.grown(extraVoxels);
    if (v.empty()) continue;
    // Cells v.lo - 1 .. v.hi - 1 read a voxel of v: points [v.lo - 1, v.hi].
    const Vec3 lo = glm::max(Vec3(v.lo - Index3(1)), Vec3(0.0));
    const Vec3 hi = glm::min(Vec3(v.hi), top);
    if (hi.x < lo.x || hi.y < lo.y || hi.z < lo.z) continue;
    out.push_back({g.voxelToWorld(lo - Vec3(kStencilSlackVoxels)), g.voxelToWorld(hi + Vec3(kStencilSlackVoxels))});
  }
  return out;
}

std::vector<WorldBox> stencilBoxes(const DirtyRegion& changed, int extraVoxels) {
  const Index3 bd = changed.brickDims();
  const std::int64_t B = changed.brickSize();
  // Runs along x, then runs of equal x-extent stacked along y, then rectangles
  // of equal extent stacked along z: brick ids are sorted z, y, x, so each
  // merge sees its candidates in order.
  struct Rect {
    std::int64_t x0, x1, y0, y1, z0, z1;  // inclusive brick coordinates
  };
  std::vector<Rect> runs;
  for (const auto id : changed.bricks()) {
    const std::int64_t x = id % bd.x, y = (id / bd.x) % bd.y, z = id / (bd.x * bd.y);
    if (!runs.empty() && runs.back().y0 == y && runs.back().z0 == z && runs.back().x1 + 1 == x) {
      runs.back().x1 = x;
    } else {
      runs.push_back({x, x, y, y, z, z});
    }
  }
  std::vector<Rect> rects;
  std::map<std::tuple<std::int64_t, std::int64_t, std::int64_t>, std::size_t> openY;
  for (const Rect& r : runs) {
    const auto key = std::make_tuple(r.z0, r.x0, r.x1);
    auto it = openY.find(key);
    if (it != openY.end() && rects[it->second].y1 + 1 == r.y0) {
      rects[it->second].y1 = r.y0;
    } else {
      openY[key] = rects.size();
      rects.push_back(r);
    }
  }
  std::vector<Rect> boxes;
  std::map<std::tuple<std::int64_t, std::int64_t, std::int64_t, std::int64_t>, std::size_t> openZ;
  for (const Rect& r : rects) {
    const auto key = std::make_tuple(r.x0, r.x1, r.y0, r.y1);
    auto it = openZ.find(key);
    if (it != openZ.end() && boxes[it->second].z1 + 1 == r.z0) {
      boxes[it->second].z1 = r.z0;
    } else {
      openZ[key] = boxes.size();
      boxes.push_back(r);
    }
  }
  std::vector<Box3> voxels;
  voxels.reserve(boxes.size());
  const Box3 all{Index3(0), changed.grid().dims};
  for (const Rect& r : boxes)
    voxels.push_back(Box3{Index3(r.x0, r.y0, r.z0) * B, Index3(r.x1 + 1, r.y1 + 1, r.z1 + 1) * B}.intersect(all));
  return stencilBoxes(changed.grid(), voxels, extraVoxels);
}

Index3 stencilCell(const SampleLattice& lattice, std::uint32_t pixel, std::uint32_t k) {
  const Index3& d = lattice.grid().dims;
  const glm::vec3 p = lattice.voxelRay(pixel).at(k);
  Index3 c;
  for (int a = 0; a < 3; ++a) {
    std::int64_t i = static_cast<int>(p[a]);
    c[a] = std::clamp<std::int64_t>(i, 0, d[a] - 2);
  }
  return c;
}

std::optional<PixelBounds> stencilFootprint(const Grid& grid, const Box3& b, const Camera& camera) {
  // The samples that read voxels of b lie in the cells [lo - 1, hi), i.e. at
  // voxel positions [lo - 1, hi] (clamped to the sampling box).
  const Vec3 lo = glm::max(Vec3(b.lo) - 1.0, Vec3(0.0)) - kStencilSlackVoxels;
  const Vec3 hi = glm::min(Vec3(b.hi), Vec3(grid.dims - Index3(1))) + kStencilSlackVoxels;
  double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
  for (int a = 0; a < 8; ++a) {
    const Vec3 v((a & 1) ? hi.x : lo.x, (a & 2) ? hi.y : lo.y, (a & 4) ? hi.z : lo.z);
    const auto p = camera.project(grid.voxelToWorld(v));
    if (!p) return std::nullopt;
    x0 = std::min(x0, p->px);
    x1 = std::max(x1, p->px);
    y0 = std::min(y0, p->py);
    y1 = std::max(y1, p->py);
  }
  // Pixel x's ray passes through x + 0.5; one pixel of margin for rounding.
  return PixelBounds{std::ceil(x0 - 0.5) - 1, std::ceil(y0 - 0.5) - 1, std::floor(x1 - 0.5) + 1,
                     std::floor(y1 - 0.5) + 1};
}

}  // namespace pp5::gp
