#pragma once
// The pixel processor's hierarchical ray-sample cache and its compositing.
//
// A RayCache holds every lattice sample of the rays of one screen tile. Each
// ray's samples are grouped in blocks of `block_size`, and each block keeps
// its partial composite for the live mode, because "over", sum and max are all
// associative: a changed sample costs one block recomputed and one walk over
// the ray's block partials, not the ray.
//
// Early ray termination ("over" only) works on blocks: walking a ray's blocks
// front to back, the walk stops before the first block at which the
// accumulated alpha has reached the threshold, so a pixel differs from the
// unterminated composite by at most 1 - threshold in any channel. The
// incremental path and a from-scratch render run the very same walk over the
// same partials, so they give the same bits; a block behind the termination
// point is left dirty, and is composited only once a change in front makes it
// reachable again.
//
// A block's partial is computed as four runs side by side (lanes 0..2 of n/4
// samples, lane 3 the rest), each folded front to back, then the four folded
// in order; "over" carries transmittance T (r += T * s.r, T *= 1 - s.a). The
// bits are a function of the samples, the block size and the mode only
// (tests/test_ray_cache.cpp pins the order down).
//
// Output: a float RGBA image of the tile, premultiplied by alpha and not
// composited over anything; toRgb8 puts it over a background for display.
//  - over:     front to back (Levoy), premultiplied colour and its alpha.
//  - additive and mip composite grey-value samples (r = g = b = v / 255, a =
//              v / 255 x step / opacity unit; gp/ray_sampler): additive the
//              sum of a times `additive_scale` (an integral of the grey level
//              along the ray), mip the largest r (the brightest grey level).
//              Either is shown through the value window (setValueWindow) as
//              premultiplied white: v over black. The fold is per channel (a
//              max of each channel alone is associative and needs no
//              tie-break).
//
// One RayCache is used by one thread at a time; caches of different tiles
// share nothing, so they can be used concurrently. composite() may use OpenMP
// over the dirty rays; every ray is composited by one thread in a fixed order,
// so the bits do not depend on the thread count.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <vector>

#include "core/ray_sample.hpp"
#include "formats/sample_runs.hpp"
#include "core/render_settings.hpp"
#include "core/tiles.hpp"
#include "rendering/zeroed_array.hpp"
#include "core/enum_names.hpp"

namespace pp5 {
class ConfigSchema;
}

namespace pp5::pp {

// The composition modes are a render setting (core/render_settings.hpp).
using pp5::CompositeMode;
// "over" | "additive" | "mip" (render.compositing); anything else is an InputError.
CompositeMode compositeModeFromName(const std::string& name);
const char* compositeModeName(CompositeMode m);

// How the cache stores a sample's premultiplied r, g, b, a.
enum class SampleFormat : std::uint8_t {
  Rgba8,  // 4 bytes, value / 255: small per-sample opacities quantise badly
  Half,   // 8 bytes, IEEE binary16, rounded to nearest even
  Float,  // 16 bytes, exact
};
SampleFormat sampleFormatFromName(const std::string& name);  // "rgba8" | "half" | "float"
// The wire form GPs send samples in for caches of format f: half for half
// (exact, see formats/sample_runs.hpp), float otherwise.
inline SampleWire sampleWireFor(SampleFormat f) { return f == SampleFormat::Half ? SampleWire::Half : SampleWire::Float; }
const char* sampleFormatName(SampleFormat f);
std::size_t sampleFormatBytes(SampleFormat f);

// [render.cache]
struct RayCacheSettings {
  int blockSize = 32;  // samples per block, a power of two
  SampleFormat format = SampleFormat::Half;
  bool earlyTermination = true;
  double terminationAlpha = 1.0 - 1.0 / 512.0;
  double additiveScale = 0.02;

  // Throws InputError naming the key when a value the schema cannot express
  // (block_size a power of two) is wrong.
  void validate() const;
};
void registerOptions(ConfigSchema& schema, RayCacheSettings& s);

// Float RGBA of one tile, premultiplied, row-major, 4 floats per pixel.
struct TileImage {
  int width = 0, height = 0;
  std::vector<float> rgba;
  const float* pixel(int x, int y) const { return rgba.data() + 4 * (static_cast<std::size_t>(y) * width + x); }
};

// What one composite() did. `changed` bounds the pixels it rewrote, in tile
// coordinates (x0, y0 relative to the tile); empty when none.
struct CompositeStats {
  std::uint64_t rays = 0;
  std::uint64_t blocks = 0;
  TileRect changed;
};

// Running totals since construction or resetCounters().
struct RayCacheCounters {
  std::uint64_t samplesPut = 0;
  std::uint64_t composites = 0;        // composite() calls
  std::uint64_t raysComposited = 0;    // rays walked and written by composite()
  std::uint64_t blocksComposited = 0;  // block partials recomputed from samples by composite()
};

class RayCache {
public:
  // `sampleCounts`: per pixel of the tile, row-major, the number of lattice
  // samples of its ray (the GP's SampleLattice). `threads`: OpenMP threads
  // for compositing, 0 = every core.
  RayCache(const TileRect& tile, int imageWidth, std::span<const std::uint16_t> sampleCounts,
           const RayCacheSettings& settings, CompositeMode live = CompositeMode::Over, int threads = 1);

  const TileRect& tile() const { return tile_; }
  CompositeMode liveMode() const { return live_; }
  SampleFormat format() const { return format_; }
  int blockSize() const { return blockSize_; }
  void setThreads(int threads) { threads_ = threads; }

  // Stores the samples (a later put of the same pixel and k replaces the
  // earlier one) and marks their blocks dirty, and their rays where the block
  // is in front of the ray's termination point. A sample outside the tile or
  // beyond its ray's count throws InvariantError; the samples before it in
  // the batch are stored.
  void put(const RaySample* samples, std::size_t n);
  void put(std::span<const RaySample> samples) { put(samples.data(), samples.size()); }
  // Puts from several threads at once, each with its own lane (0 .. lanes -
  // 1, set before they start), for threads that put samples of different
  // rays (the sampler's work tiles): a full view's millions of samples are
  // stored in parallel. Otherwise as put(); the next composite() takes the
  // lanes' dirty rays.
  void setPutLanes(int lanes);
  void put(int lane, const RaySample* samples, std::size_t n);

  // Brings the live image up to date: recomputes the dirty blocks that the
  // walks reach, recombines the dirty rays and rewrites only their pixels.
  CompositeStats composite();
  // The live mode's image, as of the last composite().
  const TileImage& image() const { return image_; }

  // Every ray of `mode` composited from the samples, storing nothing; for
  // the modes that are not live (e.g. at the end of a run). For the live mode
  // it gives the same bits as composite().
  TileImage compositeFull(CompositeMode mode) const;

  // Every sample transparent again, the image cleared; the counts stay.
  void clear();
  // New sample counts for the same tile (a new view), every sample
  // transparent; the storage is reused where it is large enough.
  void reset(std::span<const std::uint16_t> sampleCounts);
  // The same, with a new live mode.
  void reset(std::span<const std::uint16_t> sampleCounts, CompositeMode live) {
    live_ = live;
    reset(sampleCounts);
  }
  // The view's pixel stride (SampleLattice): only the pixels whose image x
  // and y are multiples of it have samples, and composite() and
  // compositeFull() show each of those over the block of pixels it stands
  // for: the next stride - 1 columns and rows within the tile (a tile that
  // starts between strided columns or rows gives the ones before its first
  // strided pixel to that pixel). 1 (every pixel) until set; a reset keeps it.
  void setPixelStride(int stride);
  int pixelStride() const { return stride_; }
  // Marks every block and ray dirty, so that the next composite() recomputes
  // the whole tile from its samples (what a full render costs).
  void invalidate();
  // A new live mode: every block's partial is recomputed by the next
  // composite(), which then gives the bits compositeFull(m) gives.
  void setLiveMode(CompositeMode m) {
    live_ = m;
    invalidate();
  }
  // The grey levels MIP and additive show as black and white
  // (render.value_window); when the window changes and the live mode is MIP
  // or additive, the next composite() recomposites every block.
  void setValueWindow(double lo, double hi);

  // Bytes held: the current view's samples, block partials, dirty and
  // touched-page flags, per-ray records, the image and the dirty-ray list.
  // The samples' storage is zeroed address space that takes memory only
  // where samples were written (ZeroedArray), so this is an upper bound.
  std::size_t memoryBytes() const;
  std::uint64_t sampleCount() const { return sampleTotal_; }
  std::uint64_t blockCount() const { return blockTotal_; }

  const RayCacheCounters& counters() const { return counters_; }
  void resetCounters() { counters_ = {}; }

  // The partial composite of one block for a mode: r, g, b and, for "over",
  // the block's transmittance (1 - alpha) so that blocks combine with one
  // multiply; for additive and mip, alpha's sum or max.
  struct Partial {
    float r, g, b, w;
  };

private:
  // Where a ray's samples are stored: the rays of a small square of the
  // tile (a group) share their storage by depth, block b of every member
  // side by side, then block b + 1: sample k of a ray lies at
  // sample + (k / block_size) * stride + k % block_size. A group's block row
  // fills about one page of memory (4 KiB), so a surface that comes into view
  // behind a few neighbouring pixels writes to one fresh page, not to one per
  // ray: a fresh page is zeroed by the kernel on its first write, which cost
  // the incremental update more than the writes (docs/benchmarks.md).
  struct Ray {
    std::uint64_t sample;  // index of the ray's first sample
    std::uint32_t block;   // index of its first block (partials_, dirty_: ray by ray)
    std::uint16_t count;   // lattice samples
    std::uint16_t end;     // blocks folded by its last walk: the termination point
    // While listed: the first and last dirty blocks in front of `end`, where
    // composite() prefetches, since a walk waits on memory for its samples.
    std::uint16_t firstDirty, lastDirty;
    std::uint16_t stride;  // samples from one of its blocks to the next
    std::uint8_t listed;   // in dirtyRays_
    std::uint64_t at(std::uint32_t k, int blockShift) const {
      return sample + static_cast<std::uint64_t>(k >> blockShift) * stride + (k & ((1u << blockShift) - 1));
    }
  };

  TileRect tile_;
  int imageWidth_;
  CompositeMode live_;
  SampleFormat format_;
  int blockSize_;
  int blockShift_;
  float transmittanceLimit_;  // terminate once T <= this; -1 = never
  float additiveScale_;
  float valueLo_ = 0.0f, valueInvWidth_ = 1.0f / 255.0f;
  int threads_;

  std::uint64_t sampleTotal_ = 0, blockTotal_ = 0;
  std::uint64_t storageSamples_ = 0;  // the storage's size in samples (>= sampleTotal_)
  std::vector<Ray> rays_;
  // One of these holds the samples, 4 values each, by format_.
  ZeroedArray<std::uint8_t> samples8_;
  ZeroedArray<std::uint16_t> samples16_;
  ZeroedArray<float> samples32_;
  std::vector<Partial> partials_;
  std::vector<std::uint8_t> dirty_;
  // One flag per page of 2^kPageShift samples of the storage to which put()
  // wrote a sample with a bit set since the last clear() or reset(); every
  // other page is all zero.
  static constexpr int kPageShift = 6;
  std::vector<std::uint8_t> touched_;
  std::vector<std::uint32_t> dirtyRays_;
  std::vector<std::vector<std::uint32_t>> laneRays_;  // dirty rays listed by put(lane, ...)
  TileImage image_;
  RayCacheCounters counters_;
  int stride_ = 1;
  std::vector<int> srcX_, srcY_;  // setPixelStride's source column and row of each

  friend struct RayCacheAccess;
  std::uint16_t blocksOf(std::uint16_t count) const {
    return static_cast<std::uint16_t>((count + (1u << blockShift_) - 1) >> blockShift_);
  }
  // Lays out the rays' storage (Ray::at) for new sample counts.
  void layOut(std::span<const std::uint16_t> sampleCounts);
  // Zeroes the touched pages and clears their flags.
  void zeroTouched();
  // The lanes' dirty rays onto dirtyRays_.
  void mergeLanes();
  // Copies the strided pixels of `changed` over the pixels they stand for;
  // the rectangle those make up.
  TileRect fillBlocks(TileImage& im, const TileRect& changed) const;
  template <SampleFormat F, CompositeMode M>
  CompositeStats compositeDirty();
  template <SampleFormat F, CompositeMode M>
  void compositeAll(TileImage& out) const;
};

// 8-bit output. Rounded to nearest, clamped to [0, 255].
// RGB: the premultiplied image over an opaque background colour (0..1).
void toRgb8(const TileImage& im, const float background[3], std::uint8_t* rgb);
// The same over black, as a new width * height * 3 buffer (what the outputs show).
std::vector<std::uint8_t> toRgb8(const TileImage& im);
// RGBA with straight (unpremultiplied) alpha, as PNG expects; colour 0 where
// alpha is 0.
void toRgba8(const TileImage& im, std::uint8_t* rgba);

}  // namespace pp5::pp

namespace pp5 {

template <>
struct EnumNames<pp::SampleFormat> {
  static constexpr std::string_view key = "render.cache.format";
  static constexpr std::array<std::pair<pp::SampleFormat, std::string_view>, 3> names{{
      {pp::SampleFormat::Rgba8, "rgba8"},
      {pp::SampleFormat::Half, "half"},
      {pp::SampleFormat::Float, "float"}}};
};

}  // namespace pp5
