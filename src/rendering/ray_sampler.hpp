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
// Which samples a changed voxel affects: rendering/stencil.hpp. Empty space, which
// sampleAll jumps over without changing the output: rendering/empty_space.hpp.
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
#include "rendering/dbuffer.hpp"
#include "core/sample_lattice.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/empty_space.hpp"
#include "rendering/opacity_correction.hpp"
#include "rendering/shade_buffer.hpp"
#include "rendering/stencil.hpp"

namespace pp5::gp {

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
// nothing to re-sample. `changedCells` (optional, marks null: none;
// ChangeTracker's): only the samples whose cell is marked, which is again
// exact under that invariant: a sample whose 8 voxels kept their shades has
// the bits the cache holds.
void sampleRegion(const ShadeBuffer& shade, const SampleLattice& lattice, const DBuffer& dbuffer,
                  const RenderSettings& settings, SampleSink& sink, const EmptySpaceMap* space = nullptr,
                  const SamplerOptions& options = {}, const EmptySpaceMap* before = nullptr,
                  CellMarks changedCells = {});

// One sample, by the same arithmetic (the reference in tests).
RaySample sampleAt(const ShadeBuffer& shade, const SampleLattice& lattice, const RenderSettings& settings,
                   std::uint32_t pixel, std::uint32_t k);

}  // namespace pp5::gp
