#pragma once
// Empty space: EmptySpaceMap marks bricks of cells whose 8-voxel stencils are
// all transparent, with each empty brick's Chebyshev distance to the nearest
// visible one, so sampleAll jumps over runs of empty bricks with one step per
// empty cube, and a ray is only walked where it crosses the bounding box of
// the visible bricks; no division per sample. Inside a visible brick it keeps
// a bit per cell, so that the sampler reads no voxels for a sample whose cell
// is all transparent: speckle leaves most cells of a visible brick so (72% of
// the cells a view of the default doll reads). Skipping never changes the
// output: a skipped sample is exactly transparent.
#include <cstdint>
#include <span>
#include <vector>

#include "core/grid.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/shade_buffer.hpp"

namespace pp5::gp {

class EmptySpaceMap {
public:
  static constexpr int kBrickCells = 8;

  EmptySpaceMap() = default;
  // Scans every voxel; threads: 0 = every core.
  explicit EmptySpaceMap(const ShadeBuffer& shade, int threads = 0);
  // After the voxels of `changed` were re-shaded: rescans them, the cells
  // and bricks whose stencils reach them, then the distances (only those
  // that bricks newly occupied lower, when no brick became empty and they
  // are few; else all). `changed` may be many short runs (the voxels whose
  // shade changed: ChangeTracker::changedRuns).
  void update(const ShadeBuffer& shade, std::span<const Box3> changed);
  // The brick level of `from` (occupancy, distances, bounds: a few kB)
  // without its cell bits, which this map then lacks (hasCellBits() false):
  // what the sampler reads of the map as it was before a change.
  void assignBricks(const EmptySpaceMap& from);

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

  // Bit i (word i / 64, bit i % 64) is set when the cell whose low corner is
  // voxel i (Grid::linear) has a voxel with alpha > 0 among its 8; for an
  // index that is no cell's (the last voxel of a row, a column, a slice) the
  // bit means nothing. Every constructed map has them.
  const std::uint64_t* cellBits() const { return cellBits_.data(); }
  bool hasCellBits() const { return !cellBits_.empty(); }
  static bool bitSet(const std::uint64_t* bits, std::int64_t i) { return (bits[i >> 6] >> (i & 63)) & 1u; }
  bool cellVisible(std::int64_t linearIndex) const { return bitSet(cellBits_.data(), linearIndex); }
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
  // Bit per voxel in linear order: alpha > 0. Both bit arrays are padded with
  // zero words, so that a cell's word reads its neighbours' words unchecked.
  std::vector<std::uint64_t> voxelBits_;
  std::vector<std::uint64_t> cellBits_;
  // After the bricks `filled` became occupied (and none became empty): the
  // distances they lower, and the occupied box; false when that would cost
  // more than recomputing them (left half done: the caller recomputes).
  bool lowerDistances(std::span<const Index3> filled);
  // The cells of a box of bricks, clipped to the grid's.
  Box3 cellsOfBricks(const Box3& bricks) const {
    return {bricks.lo * Index3(kBrickCells), glm::min(bricks.hi * Index3(kBrickCells), cellDims())};
  }
  // Voxels [first, last) (linear) into voxelBits_.
  void packVoxels(const ShadeBuffer& shade, std::int64_t first, std::int64_t last);
  // cellBits_ words [w0, w1) from voxelBits_.
  void computeCellWords(std::int64_t w0, std::int64_t w1);
  // occupied_ of one brick, from the cell bits; whether it changed.
  bool scanBrick(std::int64_t bi, std::int64_t bj, std::int64_t bk);
  void computeDistances();
};

}  // namespace pp5::gp
