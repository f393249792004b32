#pragma once
// What one incremental update really changed, voxel by voxel, so that the
// later stages do only that work. The reconstruction's dirty region is
// conservative (whole bricks around the slice and its reach): on the doll,
// of the 600k voxels it asks to re-shade, about 9k change their shade.
//
//  1. Values. The tracker keeps a copy of the grey values the shade buffer
//     was computed from. Inside the dirty region it compares them with the
//     reconstruction's output, row by row, and updates the copy. A voxel's
//     shade reads its own value and its six face neighbours' (gp/shading.hpp),
//     so only voxels within one face step of a changed value can shade
//     differently, and of those only the ones visible now (a voxel the
//     transfer function makes transparent shades to zero, as it did before
//     unless its own value changed from a visible one): shadingRuns() lists
//     them, as row runs of the boxes this GP shades.
//  2. Shades. shade() reports the voxels whose shade it changed. A ray
//     sample reads the 8 voxels of one cell (gp/stencil.hpp), so only a
//     sample whose cell has a changed voxel can differ from what the PP's
//     cache holds: changedCells() marks those cells, and changedBricks()
//     holds the kBrick^3-voxel bricks with a changed shade for the D-buffer and
//     the empty-space map.
// Skipping the rest is exact: a voxel whose inputs did not change shades to
// the same bits, and a sample whose voxels did not change interpolates to
// the same bits (no state but the values and the settings, which are fixed
// between view and style changes, when everything is re-done anyway).
#include <cstdint>
#include <span>
#include <vector>

#include "core/grid.hpp"
#include "core/transfer_function.hpp"
#include "core/volume_io.hpp"
#include "gp/dirty_region.hpp"

namespace pp5::gp {

class ChangeTracker {
public:
  // Voxels a side of changedBricks(): the D-buffer's spans are whole bricks,
  // and the sampler visits every sample in them to find the few whose cell
  // changed. 4 visits fewer than 8 and costs fewer boxes than 2
  // (docs/benchmarks.md, "Smaller changed bricks").
  static constexpr int kBrick = 4;

  ChangeTracker() = default;
  // The values the shade buffer is computed from (e.g. the empty grid).
  // The caller checks the memory: memoryBytes() of the grid and type.
  explicit ChangeTracker(const Volume& values);
  // What a tracker of grid g with values of type t holds: per voxel the copy
  // (its voxel type) and the cell mask (a byte), and the row ranges.
  static std::uint64_t bytesPerVoxel(ScalarType t) { return static_cast<std::uint64_t>(scalarBytes(t)) + 1; }
  static std::uint64_t memoryBytes(const Grid& g, ScalarType t);
  std::uint64_t memoryBytes() const { return memoryBytes(grid_, copy_.type); }

  // After a full re-shade from `values`: every value is the shaded one.
  void resync(const Volume& values);

  // Compares `values` with the copy inside `dirty` (boxes; clipped to the
  // grid), takes the new values into the copy, and returns, as one-row boxes
  // clipped to `within` (disjoint boxes), every voxel whose shade can have
  // changed: a changed value that was or is visible, or a visible voxel with
  // a changed value among its six face neighbours. `tf`: what makes a value
  // transparent (TransferFunction::transparentUpTo); null when every value
  // may be visible (the grey values of MIP and additive). The runs may hold
  // a few voxels more (each row's run is one range). Empty when no value of
  // `dirty` changed.
  std::vector<Box3> shadingRuns(const Volume& values, std::span<const Box3> dirty, std::span<const Box3> within,
                                const TransferFunction* tf);

  // The voxels whose shade changed (linear indices, any order): replaces the
  // last call's cells and bricks.
  void setShadeChanges(std::span<const std::int64_t> voxels);
  // Per cell, indexed by the linear index of its lowest voxel (cells 0 ..
  // dims - 2 per axis): non-zero when one of its 8 voxels changed its shade
  // in the last setShadeChanges().
  const std::uint8_t* changedCells() const { return cells_.data(); }
  const DirtyRegion& changedBricks() const { return bricks_; }
  std::size_t changedShades() const { return changed_.size(); }

private:
  Grid grid_;
  Volume copy_;
  // Per row (j, k), ranges of x in this call (lo > hi: none): the voxels
  // whose value changed, of those the ones visible before or now, and the
  // voxels visible now; and the rows that have an entry to clear.
  std::vector<std::int32_t> rowLo_, rowHi_, selfLo_, selfHi_, visLo_, visHi_;
  std::vector<std::int64_t> rowsTouched_;
  std::vector<std::uint8_t> cells_;
  std::vector<std::int64_t> changed_;  // the voxels behind cells_
  DirtyRegion bricks_;
  void markCells(std::uint8_t value);
};

}  // namespace pp5::gp
