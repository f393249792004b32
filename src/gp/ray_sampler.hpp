#pragma once
// Ray-sampling: the shade buffer interpolated trilinearly at the points of the
// global sample lattice, each sample's opacity corrected to the step, handed
// to a sink as RaySamples for the PP's cache.
//
//  - sampleAll: every visible sample of every ray, after a view change (the
//    cache has been cleared, so transparent samples are not sent).
//  - sampleRegion: every sample inside the D-buffer's spans, transparent ones
//    included, because the cache may hold an older, visible value there.
//
// A sample's value depends only on its lattice position and the shade buffer:
// the position is computed from k (VoxelRay::at), never accumulated, and the
// arithmetic is the same in both functions and on every thread, so the bits
// do not depend on the thread count, on the region or on which function took
// the sample.
//
// Values: the premultiplied RGBA8 voxels are interpolated in 0..255 and
// scaled to 0..1. With a the interpolated opacity and e = step /
// opacity_unit_mm, the sample's opacity is a' = 1 - (1 - a)^e and its colour
// is scaled by a' / a (a = 0 gives a zero sample). The power is a polynomial
// log2/exp2 in float, four samples at a time (relative error about 1e-6):
// the same bits on any machine, unlike libm's powf. (Bitwise claims assume
// IEEE arithmetic without contraction into FMAs: ISO C++ mode, no
// -ffast-math, as the build sets it.)
//
// Which samples a changed voxel affects: the sample at voxel position p
// (float, VoxelRay::at) reads the 8 voxels of the cell floor(p) (clamped to the
// grid's last cell), so a voxel v changes the samples with floor(p) in [v - 1,
// v] along each axis, the samples within one voxel of it. The grow rule for a
// box of changed voxels [lo, hi) is therefore: the sampling points with p in
// [lo - 1, hi] (voxel units), clipped to the sampling box [0, dims - 1], and
// widened by kStencilSlackVoxels for the float rounding of p. stencilBoxes()
// applies it; pass it the voxels whose *shade* changed (e.g.
// shadingBoxes(dirty), which already adds the gradient's reach). The D-buffer
// of those boxes then covers every sample that can have changed, plus the
// few within the slack.
//
// Empty space: EmptySpaceMap marks bricks of cells whose 8-voxel stencils are
// all transparent, with each empty brick's Chebyshev distance to the nearest
// visible one, so sampleAll jumps over runs of empty bricks with one step per
// empty cube, and a ray is only walked where it crosses the bounding box of
// the visible bricks; no division per sample. Skipping never changes the
// output: a skipped sample is exactly transparent.
//
// Output goes to a SampleSink in batches. The image is cut into square work
// tiles of SamplerOptions::tileSize pixels (a divisor of the PP's tile, so a
// batch belongs to one PP); a tile is sampled by one thread, its pixels in
// row-major order, each ray's k ascending, and handed over in batches of at
// most batchSamples. Batches of different tiles arrive from several threads
// at once, in no fixed order; each batch's contents are fixed. A sink that
// needs a fixed overall order sorts by tile (SampleCollector does).
//
// A GP's share (design brief, "Two GP partitionings"): SamplerOptions can
// restrict both functions to the samples one GP owns, and the restricted
// output is exactly the unrestricted output filtered by the ownership test,
// bit for bit, so a partition of the cells or of the work tiles emits every
// sample once, with the same bits as one unrestricted call.
//  - ownedCells (slab): the samples whose stencil cell (stencilCell()) lies in
//    a box of cells. The test is the exact cell of the interpolation path,
//    not geometry: along a ray each axis' cell is a monotone function of k
//    (p = base + float(k) * delta rounds monotonically), so the owned samples
//    of a ray are one run of k. A ray is first clipped to the owned box grown
//    by the skip margin (outwards to infinity on a face of the grid, where the
//    cell is clamped) and intersected with the visible bricks' bounds, a
//    conservative range; the run's ends are then found in it by the exact
//    cell test (a galloping search, usually a sample or two), so a GP walks
//    no ray through other GPs' cells.
//  - workTiles (tile): only the work tiles with a non-zero mask entry; the
//    others cost nothing. A GP that owns screen tiles of the PP's size marks
//    the work tiles inside them (the work tile divides the PP's tile).
// The two combine (a sample must pass both). Batches keep their form: a
// batch still belongs to one work tile, in the same order as before, with
// the samples of other owners left out.
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <span>
#include <vector>

#include "core/ray_sample.hpp"
#include "core/render_settings.hpp"
#include "gp/dbuffer.hpp"
#include "gp/dirty_region.hpp"
#include "gp/sample_lattice.hpp"
#include "gp/shade_buffer.hpp"

namespace pp5::gp {

// Voxel units added around each stencil box: far more than the float error of
// a sample position (a few 1e-5 voxel in a 1024^3 grid), so the D-buffer
// never misses a sample whose stencil touches a changed voxel.
inline constexpr double kStencilSlackVoxels = 1.0 / 256.0;

// The world boxes (sampling-box clipped) that hold every lattice sample whose
// trilinear stencil touches a voxel of `changed` grown by `extraVoxels`.
std::vector<WorldBox> stencilBoxes(const Grid& grid, std::span<const Box3> changed, int extraVoxels = 0);
// The same for the bricks of `changed`: runs of bricks are merged into larger
// boxes first, so the D-buffer scan-converts a few boxes rather than many.
std::vector<WorldBox> stencilBoxes(const DirtyRegion& changed, int extraVoxels = 0);

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

class SampleSink {
public:
  virtual ~SampleSink() = default;
  // Called concurrently from the sampling threads (`thread` in 0..threads-1,
  // so a sink can keep per-thread buffers); every sample of the batch lies in
  // work tile `tile` (row-major over the image's tiles). The span is valid
  // during the call only.
  virtual void consume(int thread, std::uint32_t tile, std::span<const RaySample> samples) = 0;
};

// Any callable with consume's signature, called concurrently.
class CallbackSink final : public SampleSink {
public:
  using Fn = std::function<void(int, std::uint32_t, std::span<const RaySample>)>;
  explicit CallbackSink(Fn f) : f_(std::move(f)) {}
  void consume(int thread, std::uint32_t tile, std::span<const RaySample> s) override { f_(thread, tile, s); }

private:
  Fn f_;
};

// Keeps every sample, for tests and the serial reference: samples() lists
// them tile by tile, each tile's in emission order, the same for any thread
// count.
class SampleCollector final : public SampleSink {
public:
  void consume(int thread, std::uint32_t tile, std::span<const RaySample> samples) override;
  std::vector<RaySample> samples() const;
  std::size_t size() const;
  void clear();

private:
  mutable std::mutex m_;
  std::vector<std::vector<RaySample>> tiles_;
};

struct SamplerOptions {
  int tileSize = 32;                 // pixels per side of a work tile
  std::size_t batchSamples = 4096;   // most samples per consume(); keeps a batch in cache
  // Only the samples whose stencil cell (stencilCell()) lies in this half-open
  // box of cells (cell c: voxels c .. c + 1; cells 0 .. dims - 2 per axis, the
  // box is clipped to them); unset = all. Partitioning the cells partitions
  // the samples.
  std::optional<Box3> ownedCells;
  // Only the work tiles whose entry is non-zero: row-major over the image's
  // work tiles, ceil(width / tileSize) * ceil(height / tileSize) entries
  // (workTileCount()); empty = all.
  std::vector<std::uint8_t> workTiles;
};

// The work tiles of a width x height image: ceil(width / tileSize) per row,
// rows top to bottom; the size of SamplerOptions::workTiles.
std::uint32_t workTileCount(int width, int height, int tileSize);

// Every sample with a > 0 of every ray (of the share options.ownedCells and
// options.workTiles select); threads from settings.threads. `space`: the
// shade buffer's empty-space map, built here when null.
void sampleAll(const ShadeBuffer& shade, const SampleLattice& lattice, const RenderSettings& settings,
               SampleSink& sink, const EmptySpaceMap* space = nullptr, const SamplerOptions& options = {});

// Every lattice sample inside the D-buffer's spans (t_k in [t_in, t_out]),
// transparent ones included (of the share the options select). `space`
// (optional) only saves the interpolation of samples it knows are
// transparent. `before` (optional, with `space`): the map of the shade
// buffer before this update; a sample that both maps know to be transparent
// was 0 and stays 0, so it is not emitted at all. That is exact only when the
// receiving cache holds every sample of the previous shade buffer (the
// incremental pipeline's invariant): water around an object then costs
// nothing to re-sample.
void sampleRegion(const ShadeBuffer& shade, const SampleLattice& lattice, const DBuffer& dbuffer,
                  const RenderSettings& settings, SampleSink& sink, const EmptySpaceMap* space = nullptr,
                  const SamplerOptions& options = {}, const EmptySpaceMap* before = nullptr);

// One sample, by the same arithmetic (the reference in tests).
RaySample sampleAt(const ShadeBuffer& shade, const SampleLattice& lattice, const RenderSettings& settings,
                   std::uint32_t pixel, std::uint32_t k);

// The voxel cell (its lowest corner) whose 8 voxels sample k of `pixel` reads:
// the cell SamplerOptions::ownedCells tests, by the sampler's arithmetic.
Index3 stencilCell(const SampleLattice& lattice, std::uint32_t pixel, std::uint32_t k);

// 1 - (1 - a)^e for a in [0, 1], e > 0: the opacity correction, as the
// sampler computes it.
float correctOpacity(float a, float e);

}  // namespace pp5::gp
