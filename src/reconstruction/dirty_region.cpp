#include "reconstruction/dirty_region.hpp"

#include <algorithm>
#include <cmath>

#include "core/error.hpp"

namespace pp5::gp {

DirtyRegion::DirtyRegion(const Grid& g, int brickSize) : grid_(g), brick_(brickSize) {
  PP5_CHECK_GT(brickSize, 0);
  bdims_ = (g.dims + Index3(brick_ - 1)) / Index3(brick_);
  // Brick indices are 32-bit; a 16-voxel brick allows grids of 2^44 voxels.
  PP5_CHECK_LE(static_cast<std::uint64_t>(bdims_.x) * bdims_.y * bdims_.z, std::uint64_t{0xffffffffu});
}

void DirtyRegion::normalize() {
  std::sort(bricks_.begin(), bricks_.end());
  bricks_.erase(std::unique(bricks_.begin(), bricks_.end()), bricks_.end());
}

void DirtyRegion::addBrick(std::int64_t bi, std::int64_t bj, std::int64_t bk) {
  if (bi < 0 || bj < 0 || bk < 0 || bi >= bdims_.x || bj >= bdims_.y || bk >= bdims_.z) return;
  const auto id = static_cast<std::uint32_t>((bk * bdims_.y + bj) * bdims_.x + bi);
  auto it = std::lower_bound(bricks_.begin(), bricks_.end(), id);
  if (it == bricks_.end() || *it != id) bricks_.insert(it, id);
}

void DirtyRegion::addBox(const Box3& voxels) {
  const Box3 b = voxels.intersect({Index3(0), grid_.dims});
  if (b.empty()) return;
  const Index3 lo = b.lo / Index3(brick_);
  const Index3 hi = (b.hi - Index3(1)) / Index3(brick_);
  for (std::int64_t k = lo.z; k <= hi.z; ++k)
    for (std::int64_t j = lo.y; j <= hi.y; ++j)
      for (std::int64_t i = lo.x; i <= hi.x; ++i)
        bricks_.push_back(static_cast<std::uint32_t>((k * bdims_.y + j) * bdims_.x + i));
  normalize();
}

void DirtyRegion::merge(const DirtyRegion& other) {
  PP5_CHECK_EQ(other.brick_, brick_);
  bricks_.insert(bricks_.end(), other.bricks_.begin(), other.bricks_.end());
  normalize();
}

DirtyRegion DirtyRegion::grown(int voxels) const {
  DirtyRegion r(grid_, brick_);
  for (auto id : bricks_) {
    const Box3 b = brickBox(id).grown(voxels);
    const Box3 c = b.intersect({Index3(0), grid_.dims});
    const Index3 lo = c.lo / Index3(brick_);
    const Index3 hi = (c.hi - Index3(1)) / Index3(brick_);
    for (std::int64_t k = lo.z; k <= hi.z; ++k)
      for (std::int64_t j = lo.y; j <= hi.y; ++j)
        for (std::int64_t i = lo.x; i <= hi.x; ++i)
          r.bricks_.push_back(static_cast<std::uint32_t>((k * bdims_.y + j) * bdims_.x + i));
  }
  r.normalize();
  return r;
}

bool DirtyRegion::containsVoxel(std::int64_t i, std::int64_t j, std::int64_t k) const {
  if (!grid_.contains(i, j, k)) return false;
  const auto id = static_cast<std::uint32_t>(((k / brick_) * bdims_.y + j / brick_) * bdims_.x + i / brick_);
  return std::binary_search(bricks_.begin(), bricks_.end(), id);
}

Box3 DirtyRegion::brickBox(std::uint32_t brick) const {
  const std::int64_t id = brick;
  const Index3 b(id % bdims_.x, (id / bdims_.x) % bdims_.y, id / (static_cast<std::int64_t>(bdims_.x) * bdims_.y));
  const Box3 box{b * Index3(brick_), (b + Index3(1)) * Index3(brick_)};
  return box.intersect({Index3(0), grid_.dims});
}

std::vector<Box3> DirtyRegion::boxes() const {
  std::vector<Box3> out;
  out.reserve(bricks_.size());
  for (auto id : bricks_) out.push_back(brickBox(id));
  return out;
}

std::uint64_t DirtyRegion::voxelCount() const {
  std::uint64_t n = 0;
  for (auto id : bricks_) n += brickBox(id).voxelCount();
  return n;
}

Box3 DirtyRegion::bounds() const {
  if (bricks_.empty()) return {};
  Box3 b{grid_.dims, Index3(0)};
  for (auto id : bricks_) {
    const Box3 x = brickBox(id);
    b.lo = glm::min(b.lo, x.lo);
    b.hi = glm::max(b.hi, x.hi);
  }
  return b;
}

namespace {

// Separating-axis test between an oriented box and an axis-aligned box.
struct Obb {
  Vec3 centre;
  Vec3 axis[3];  // unit
  Vec3 half;
};

bool overlaps(const Obb& o, const Vec3& boxMin, const Vec3& boxMax) {
  const Vec3 c = (boxMin + boxMax) * 0.5;
  const Vec3 e = (boxMax - boxMin) * 0.5;
  const Vec3 d = o.centre - c;
  // Tolerance: floating error must never drop a brick that a voxel on the
  // boundary belongs to; a false positive only costs a little work.
  constexpr double kEps = 1e-6;
  auto separated = [&](const Vec3& L) {
    const double len = glm::length(L);
    if (len < 1e-12) return false;
    const Vec3 n = L / len;
    const double rBox = e.x * std::abs(n.x) + e.y * std::abs(n.y) + e.z * std::abs(n.z);
    const double rObb = o.half.x * std::abs(glm::dot(o.axis[0], n)) + o.half.y * std::abs(glm::dot(o.axis[1], n)) +
                        o.half.z * std::abs(glm::dot(o.axis[2], n));
    return std::abs(glm::dot(d, n)) > rBox + rObb + kEps;
  };
  const Vec3 world[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  for (const auto& a : world)
    if (separated(a)) return false;
  for (const auto& a : o.axis)
    if (separated(a)) return false;
  for (const auto& a : world)
    for (const auto& b : o.axis)
      if (separated(glm::cross(a, b))) return false;
  return true;
}

}  // namespace

void addOrientedSlab(DirtyRegion& region, const Vec3& origin, const Vec3& edgeU, const Vec3& edgeV,
                     const Vec3& reachMm) {
  const Grid& g = region.grid();
  const double lu = glm::length(edgeU), lv = glm::length(edgeV);
  PP5_CHECK_GT(lu, 0.0);
  PP5_CHECK_GT(lv, 0.0);
  Obb o;
  o.axis[0] = edgeU / lu;
  o.axis[1] = edgeV / lv;
  o.axis[2] = glm::normalize(glm::cross(edgeU, edgeV));
  o.half = Vec3(lu * 0.5 + reachMm.x, lv * 0.5 + reachMm.y, reachMm.z);
  o.centre = origin + edgeU * 0.5 + edgeV * 0.5;

  // Candidate bricks: those inside the oriented box's axis-aligned bounds.
  Vec3 ext(0.0);
  for (int a = 0; a < 3; ++a) ext += glm::abs(o.axis[a]) * o.half[a];
  const Vec3 lo = glm::floor(g.worldToVoxel(o.centre - ext));
  const Vec3 hi = glm::ceil(g.worldToVoxel(o.centre + ext));
  const Box3 vox = Box3{Index3(lo), Index3(hi) + Index3(1)}.intersect({Index3(0), g.dims});
  if (vox.empty()) return;
  const int B = region.brickSize();
  const Index3 blo = vox.lo / Index3(B), bhi = (vox.hi - Index3(1)) / Index3(B);
  for (std::int64_t k = blo.z; k <= bhi.z; ++k)
    for (std::int64_t j = blo.y; j <= bhi.y; ++j)
      for (std::int64_t i = blo.x; i <= bhi.x; ++i) {
        const Index3 b(i, j, k);
        const Index3 vlo = b * Index3(B);
        const Index3 vhi = glm::min((b + Index3(1)) * Index3(B), g.dims) - Index3(1);
        // Voxel centres of the brick: a voxel changes only if its centre is inside the support.
        if (overlaps(o, g.voxelToWorld(Vec3(vlo)), g.voxelToWorld(Vec3(vhi)))) region.addBrick(i, j, k);
      }
}

}  // namespace pp5::gp
