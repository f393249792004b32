#pragma once
// What one incremental update really changed, voxel by voxel, so that the
// later stages do only that work. The reconstruction's dirty region is
// conservative (whole bricks around the slice and its reach): on the doll,
// of the 600k voxels it asks to re-shade, about 9k change their shade.
//
//  1. Values. Which values changed the tracker learns in one of two ways.
//     Either the reconstructor lists the rows it changed, bit for bit
//     (Reconstructor::reportsChangedRuns, the tent method), or the tracker
//     keeps a copy of the grey values the shade buffer was computed from and
//     compares it with the reconstruction's output inside the dirty region,
//     row by row, updating the copy (every other reconstructor). A voxel's
//     shade reads its own value and its six face neighbours'
//     (rendering/shading.hpp), so only voxels within one face step of a changed
//     value can shade differently, and of those only the ones visible now (a
//     voxel the transfer function makes transparent shades to zero, as it
//     did before unless its own value changed from a visible one, or, without
//     the copy, unless its shade was not zero): shadingRuns() lists them, as
//     row runs of the boxes this GP shades.
//  2. Shades. shade() reports the voxels whose shade it changed. A ray
//     sample reads the 8 voxels of one cell (rendering/stencil.hpp), so only a
//     sample whose cell has a changed voxel can differ from what the PP's
//     cache holds: changedCells() marks those cells, changedBricks()
//     holds the kBrick^3-voxel bricks with a changed shade for the D-buffer,
//     and changedRuns() the voxels themselves, as runs, for the empty-space
//     map.
// Skipping the rest is exact: a voxel whose inputs did not change shades to
// the same bits, and a sample whose voxels did not change interpolates to
// the same bits (no state but the values and the settings, which are fixed
// between view and style changes, when everything is re-done anyway).
#include <cstdint>
#include <span>
#include <vector>

#include "core/grid.hpp"
#include "core/transfer_function.hpp"
#include "formats/volume_io.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/shade_buffer.hpp"

namespace pp5::gp {

class ChangeTracker {
public:
  // Voxels a side of changedBricks(): the D-buffer's spans are whole bricks,
  // and the sampler visits every sample in them to find the few whose cell
  // changed. 4 visits fewer than 8 and costs fewer boxes than 2
  // (docs/benchmarks.md, "Smaller changed bricks").
  static constexpr int kBrick = 4;

  ChangeTracker() = default;
  // The values the shade buffer `shades` is computed from (e.g. the empty
  // grid). compare: keep a copy of the values and find changes by comparing
  // (the first shadingRuns); otherwise the caller reports them (the second),
  // and the tracker keeps a bit per voxel, whether its shade is not zero,
  // and a bound on each row's values.
  // The caller checks the memory: memoryBytes() of the grid, type and form.
  ChangeTracker(const Volume& values, const ShadeBuffer& shades, bool compare);
  // What a tracker of grid g with values of type t holds: per voxel the cell
  // mask (a byte) and, when it compares, the copy (its voxel type), else the
  // shade bit; and the row ranges. bytesPerVoxel rounds the bit up to a byte.
  static std::uint64_t bytesPerVoxel(ScalarType t, bool compare) {
    return (compare ? static_cast<std::uint64_t>(scalarBytes(t)) : 1) + 1;
  }
  static std::uint64_t memoryBytes(const Grid& g, ScalarType t, bool compare);
  std::uint64_t memoryBytes() const { return memoryBytes(grid_, type_, compares()); }
  bool compares() const { return compare_; }

  // After a full re-shade of `values` into `shades`: every value is the shaded one.
  void resync(const Volume& values, const ShadeBuffer& shades);

  // The comparing form. Compares `values` with the copy inside `dirty`
  // (boxes; clipped to the grid), takes the new values into the copy, and
  // returns, as one-row boxes clipped to `within` (disjoint boxes), every
  // voxel whose shade can have changed: a changed value that was or is
  // visible, or a visible voxel with a changed value among its six face
  // neighbours. `tf`: what makes a value transparent
  // (TransferFunction::transparentUpTo); null when every value may be
  // visible (the grey values of MIP and additive). The runs may hold a few
  // voxels more (each row's run is one range). Empty when no value of
  // `dirty` changed.
  std::vector<Box3> shadingRuns(const Volume& values, std::span<const Box3> dirty, std::span<const Box3> within,
                                const TransferFunction* tf);
  // The reported form: `changed` holds every voxel whose value changed since
  // the last call (runs clipped to the grid; they may overlap and hold
  // unchanged voxels). The same runs as above, with "was visible" read as
  // "its shade was not zero" (a transparent value shades to zero).
  std::vector<Box3> shadingRuns(const Volume& values, std::span<const RowRun> changed, std::span<const Box3> within,
                                const TransferFunction* tf);
  // The same, clipped to one box (the share of a GP that shades one region
  // whatever changed): only the rows next to a change are visited, and the
  // caller need not work out the shading boxes of the dirty region.
  std::vector<Box3> shadingRuns(const Volume& values, std::span<const RowRun> changed, const Box3& region,
                                const TransferFunction* tf);

  // The voxels whose shade changed (linear indices, any order), now as in
  // `shades`: replaces the last call's cells and bricks.
  void setShadeChanges(std::span<const std::int64_t> voxels, const ShadeBuffer& shades);
  // The cells (cells 0 .. dims - 2 per axis) of which one of the 8 voxels
  // changed its shade in the last setShadeChanges(). Each call marks with a
  // new value (1 to 255, then the marks are cleared once), so the last
  // call's marks are left where they are.
  CellMarks changedCells() const { return {cells_.data(), mark_}; }
  const DirtyRegion& changedBricks() const { return bricks_; }
  // The same voxels as one-row boxes (runs along x), in the order they
  // were given (ascending as shade() reports them).
  std::span<const Box3> changedRuns() const { return runs_; }
  std::size_t changedShades() const { return changed_.size(); }

private:
  Grid grid_;
  ScalarType type_ = ScalarType::F32;
  bool compare_ = true;
  Volume copy_;  // empty when the changes are reported
  // Reported: bit v % 64 of word v / 64 set when voxel v's shade is not 0;
  // and per row (j, k), at least its largest value (a NaN counts as
  // infinity): a row whose bound is transparent has no visible voxel, and
  // its values need not be read.
  std::vector<std::uint64_t> shadedBits_;
  std::vector<float> rowMax_;
  // Whether row `row` (k * dims.y + j) holds only transparent values, by
  // rowMax_ (reported form): its bound is below `visibleFrom`, the least
  // value the transfer function shows (visibleFrom() in the .cpp; -infinity
  // without one, when nothing is transparent).
  bool transparentRow(std::int64_t row, float visibleFrom) const {
    return !compare_ && rowMax_[static_cast<std::size_t>(row)] < visibleFrom;
  }
  // Per row (j, k), ranges of x in this call (lo > hi: none): the voxels
  // whose value changed, and of those the ones visible before or now (one
  // record a row: a row's neighbours are read together); and the rows that
  // have an entry to clear.
  struct RowRanges {
    std::int32_t lo, hi, selfLo, selfHi;
  };
  std::vector<RowRanges> ranges_;
  std::vector<std::int64_t> rowsTouched_;
  void noteRow(std::int64_t row, std::int32_t lo, std::int32_t hi, std::int32_t selfLo, std::int32_t selfHi);
  // The reported form's first step: the rows' ranges from `changed`.
  void noteReported(const Volume& values, std::span<const RowRun> changed, const TransferFunction* tf);
  // From the rows' ranges: the runs to shade within `within`, or with
  // `region` within it, visiting only the rows next to a change (and the
  // ranges cleared).
  std::vector<Box3> runsWithin(const Volume& values, std::span<const Box3> within, const TransferFunction* tf,
                               const Box3* region = nullptr);
  std::vector<std::uint8_t> rowMarks_;  // runsWithin's marks of rows, all 0 between calls
  std::vector<std::uint8_t> cells_;
  std::uint8_t mark_ = 0;  // cells_ == mark_: changed in the last setShadeChanges (0: before the first)
  std::vector<std::int64_t> changed_;  // the voxels behind cells_
  DirtyRegion bricks_;
  std::vector<Box3> runs_;
  void markCells(std::uint8_t value);
  // f(i0, i1, j, k) for each run of consecutive voxels of a row in changed_.
  template <class F>
  void forEachRun(F&& f) const;
};

}  // namespace pp5::gp
