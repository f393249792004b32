#pragma once
// Empty space: EmptySpaceMap marks bricks of cells whose 8-voxel stencils are
// all transparent, with each empty brick's Chebyshev distance to the nearest
// visible one, so sampleAll jumps over runs of empty bricks with one step per
// empty cube, and a ray is only walked where it crosses the bounding box of
// the visible bricks; no division per sample. Skipping never changes the
// output: a skipped sample is exactly transparent.
#include <cstdint>
#include <span>
#include <vector>

#include "core/grid.hpp"
#include "gp/dirty_region.hpp"
#include "gp/shade_buffer.hpp"

namespace pp5::gp {

class EmptySpaceMap {
public:
  static constexpr int kBrickCells = 8;

  EmptySpaceMap() = default;
  // Scans every voxel; threads: 0 = every core.
  explicit EmptySpaceMap(const ShadeBuffer& shade, int threads = 0);
  // After the voxels of `changed` were re-shaded: rescans the bricks whose
  // stencils reach them, then the distances.
  void update(const ShadeBuffer& shade, std::span<const Box3> changed);

  const Grid& grid() const { return grid_; }
  Index3 brickDims() const { return bdims_; }
  // Cells per axis: dims - 1.
  Index3 cellDims() const { return grid_.dims - Index3(1); }
  // 0: some cell of the brick has a voxel with alpha > 0 in its stencil.
  // d > 0: every brick within Chebyshev distance d - 1 of it (in bricks) is
  // empty. Saturates at 255.
  const std::uint8_t* distances() const { return dist_.data(); }
  std::uint8_t distance(std::int64_t bi, std::int64_t bj, std::int64_t bk) const {
    return dist_[static_cast<std::size_t>((bk * bdims_.y + bj) * bdims_.x + bi)];
  }
  double emptyFraction() const;
  // The cells of the bricks with a visible cell, as one box (empty when there
  // are none): a ray only needs walking where it crosses it.
  const Box3& occupiedCells() const { return occupiedCells_; }
  // Disjoint boxes of voxels, clipped to `within`, that hold every voxel of
  // `within` whose alpha was above 0 in the scanned shade buffer: the 8^3
  // voxel bricks that the cells of an occupied brick read, in runs along x.
  // A voxel outside them was transparent, so premultiplied all zero, and
  // stays so under any view (opacity does not depend on the view): a view
  // change needs to re-light only these (SerialPipeline::setCamera).
  std::vector<Box3> visibleVoxelBoxes(const Box3& within) const;

private:
  Grid grid_;
  Index3 bdims_{0};
  Box3 occupiedCells_;
  std::vector<std::uint8_t> occupied_;
  std::vector<std::uint8_t> dist_;
  void scanBrick(const ShadeBuffer& shade, std::int64_t bi, std::int64_t bj, std::int64_t bk);
  // Whether any voxel of the box (inside the grid) is visible.
  bool anyVisible(const ShadeBuffer& shade, const Box3& voxels) const;
  void computeDistances();
};

}  // namespace pp5::gp
