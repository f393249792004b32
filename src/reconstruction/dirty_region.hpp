#pragma once
// The part of the grid that one frame changed, as a set of fixed-size bricks.
// Every later stage (shading, ray-sampling) limits its work to it, so it must
// cover every changed voxel and stay small for slices tilted across the grid.
#include <cstdint>
#include <limits>
#include <vector>

#include "core/grid.hpp"

namespace pp5::gp {

// Half-open voxel box [lo, hi).
struct Box3 {
  Index3 lo{0};
  Index3 hi{0};
  bool empty() const { return hi.x <= lo.x || hi.y <= lo.y || hi.z <= lo.z; }
  std::uint64_t voxelCount() const {
    return empty() ? 0
                   : static_cast<std::uint64_t>(hi.x - lo.x) * static_cast<std::uint64_t>(hi.y - lo.y) *
                         static_cast<std::uint64_t>(hi.z - lo.z);
  }
  bool contains(std::int64_t i, std::int64_t j, std::int64_t k) const {
    return i >= lo.x && i < hi.x && j >= lo.y && j < hi.y && k >= lo.z && k < hi.z;
  }
  Box3 intersect(const Box3& o) const { return {glm::max(lo, o.lo), glm::min(hi, o.hi)}; }
  Box3 grown(std::int64_t n) const { return {lo - Index3(n), hi + Index3(n)}; }
  bool operator==(const Box3&) const = default;
};

// One run of voxels (i0 .. i1, j, k) along a grid row, both ends included;
// newMax: at least every value the run's voxels were given (a NaN counts as
// infinity), infinity when not known.
struct RowRun {
  std::int32_t j = 0, k = 0, i0 = 0, i1 = -1;
  float newMax = std::numeric_limits<float>::infinity();
  bool operator==(const RowRun&) const = default;
};

// Cells (indexed by the linear index of their lowest voxel) marked as
// changed: cell c is when marks[c] == mark (ChangeTracker's; a new mark per
// update, so the last update's marks need no clearing).
struct CellMarks {
  const std::uint8_t* marks = nullptr;
  std::uint8_t mark = 1;
  bool changed(std::int64_t cell) const { return marks[cell] == mark; }
};

class DirtyRegion {
public:
  static constexpr int kDefaultBrick = 16;

  DirtyRegion() = default;
  DirtyRegion(const Grid& g, int brickSize = kDefaultBrick);

  const Grid& grid() const { return grid_; }
  int brickSize() const { return brick_; }
  Index3 brickDims() const { return bdims_; }

  void clear() { bricks_.clear(); }
  bool empty() const { return bricks_.empty(); }
  // Marks every brick that overlaps the voxel box (clipped to the grid).
  void addBox(const Box3& voxels);
  void addBrick(std::int64_t bi, std::int64_t bj, std::int64_t bk);
  void merge(const DirtyRegion& other);
  // Every brick grown by `voxels` voxels on each side (e.g. the shading margin).
  DirtyRegion grown(int voxels) const;

  bool containsVoxel(std::int64_t i, std::int64_t j, std::int64_t k) const;
  // Brick linear indices, sorted and unique.
  const std::vector<std::uint32_t>& bricks() const { return bricks_; }
  // The voxel box of one brick, clipped to the grid.
  Box3 brickBox(std::uint32_t brick) const;
  std::vector<Box3> boxes() const;
  std::uint64_t voxelCount() const;
  Box3 bounds() const;

private:
  Grid grid_;
  int brick_ = kDefaultBrick;
  Index3 bdims_{0};
  std::vector<std::uint32_t> bricks_;  // sorted, unique
  void normalize();
};

// The bricks that a planar rectangle touches when every point on it spreads
// up to `reachMm` (a box of half-widths `reachMm` along the rectangle's own
// axes) - an oriented box tested against each brick with the separating-axis
// test, so a tilted slice dirties only the bricks near its plane.
// The rectangle: corner `origin`, edge vectors `edgeU`, `edgeV` (mm, world).
void addOrientedSlab(DirtyRegion& region, const Vec3& origin, const Vec3& edgeU, const Vec3& edgeV,
                     const Vec3& reachMm);

}  // namespace pp5::gp
