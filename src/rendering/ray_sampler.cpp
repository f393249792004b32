#include "rendering/ray_sampler.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

#include <omp.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.hpp"
#include "rendering/interpolator.hpp"
#include "rendering/opacity_correction.hpp"
#include "core/simd.hpp"
#include "core/threads.hpp"

namespace pp5::gp {

using namespace simd;
using opacity::correctLanes;

namespace {

// One thread's output: a batch that goes to the sink when full or when the
// tile ends.
class Batcher {
public:
  Batcher(SampleSink& sink, int thread, std::size_t capacity)
      : sink_(sink), thread_(thread), cap_(capacity), buf_(capacity) {}
  void startTile(std::uint32_t tile) { tile_ = tile; }
  // Room for up to `want` samples (at least one), written by the caller.
  RaySample* append(std::size_t want, std::size_t& got) {
    if (used_ == cap_) flush();
    got = std::min(want, cap_ - used_);
    RaySample* p = buf_.data() + used_;
    used_ += got;
    return p;
  }
  void flush() {
    if (used_ == 0) return;
    sink_.consume(thread_, tile_, std::span<const RaySample>(buf_.data(), used_));
    used_ = 0;
  }

private:
  SampleSink& sink_;
  int thread_;
  std::size_t cap_;
  std::uint32_t tile_ = 0;
  std::vector<RaySample> buf_;
  std::size_t used_ = 0;
};

// One ray's interpolated samples, waiting for their opacity correction, which
// runs over four samples at a time (it is most of a sample's arithmetic).
class RayStage {
public:
  // grey: the shade buffer holds grey values (ShadeSettings::greyValues), and
  // a sample is (v, v, v, v * exponent) with v the interpolated grey level /
  // 255: MIP takes the largest v, additive sums v times the step in units of
  // render.opacity_unit_mm, so neither depends on the step.
  RayStage(int maxSamples, float exponent, bool grey) : e_(exponent), grey_(grey) {
    const std::size_t cap = static_cast<std::size_t>(maxSamples) + 4;
    rgba_.resize(4 * cap);
    a_.resize(cap);
    k_.resize(cap);
    ap_.resize(cap);
    scale_.resize(cap);
  }
  // Where the next sample's interpolated r, g, b, a go.
  float* slot() { return rgba_.data() + 4 * n_; }
  void commit(std::uint32_t k) {
    a_[n_] = rgba_[4 * n_ + 3];
    k_[n_++] = k;
  }
  void emit(std::uint32_t pixel, Batcher& out) {
    if (n_ == 0) return;
    if (grey_) return emitGrey(pixel, out);
    for (std::size_t i = n_; i % 4 != 0; ++i) a_[i] = 0.0f;
    for (std::size_t i = 0; i < n_; i += 4) {
      F4 a255;
      std::memcpy(&a255, a_.data() + i, sizeof(F4));
      F4 ap = splat(0.0f), scale = splat(0.0f);
      // Transparent runs (sampleRegion rewrites them too) need no arithmetic.
      if (anyPositive(a255)) {
        ap = correctLanes(a255 * splat(1.0f / 255.0f), e_);
        scale = select(a255 > splat(0.0f), ap / a255, splat(0.0f));
      }
      std::memcpy(ap_.data() + i, &ap, sizeof(F4));
      std::memcpy(scale_.data() + i, &scale, sizeof(F4));
    }
    for (std::size_t i = 0; i < n_;) {
      std::size_t m;
      RaySample* dst = out.append(n_ - i, m);
      for (std::size_t j = 0; j < m; ++j, ++i) {
        const float* c = rgba_.data() + 4 * i;
        dst[j] = RaySample{pixel, k_[i], c[0] * scale_[i], c[1] * scale_[i], c[2] * scale_[i], ap_[i]};
      }
    }
    n_ = 0;
  }

private:
  // The grey-value samples of MIP and additive, out of line so that the
  // colour path inlines as it did.
  [[gnu::noinline]] void emitGrey(std::uint32_t pixel, Batcher& out) {
    for (std::size_t i = 0; i < n_;) {
      std::size_t m;
      RaySample* dst = out.append(n_ - i, m);
      for (std::size_t j = 0; j < m; ++j, ++i) {
        const float v = rgba_[4 * i] * (1.0f / 255.0f);
        dst[j] = RaySample{pixel, k_[i], v, v, v, v * e_};
      }
    }
    n_ = 0;
  }

  float e_;
  bool grey_;
  std::size_t n_ = 0;
  std::vector<float> rgba_, a_, ap_, scale_;
  std::vector<std::uint32_t> k_;
};

// Margin (voxels) by which an empty cube is shrunk before a ray jumps across
// it: a skipped sample is then inside the cube by far more than the float
// error of its position.
constexpr double kSkipMarginVoxels = 1.0 / 64.0;

// Jumps along a ray over a cube of empty bricks: the cube of bricks within
// d - 1 of brick b is empty, so the next sample worth looking at is where
// the ray leaves it, per axis at k = (b + d) * slope + offset (b - d + 1
// going down), the cube shrunk by the margin.
struct BrickJump {
  double inv[3], slope[3], offset[3];
  int side[3];
  explicit BrickJump(const VoxelRay& vr) {
    for (int a = 0; a < 3; ++a) {
      const double dl = vr.delta[a];
      inv[a] = dl != 0.0 ? 1.0 / dl : 0.0;
      side[a] = inv[a] > 0.0 ? 1 : (inv[a] < 0.0 ? -1 : 0);
      slope[a] = EmptySpaceMap::kBrickCells * inv[a];
      offset[a] = (-static_cast<double>(vr.base[a]) - side[a] * kSkipMarginVoxels) * inv[a];
    }
  }
  // The sample after the cube (at least k + 1), or kEnd + 1 when the cube reaches past kEnd.
  template <class K>
  K next(const int (&b)[3], int d, K k, K kEnd) const {
    double kExit = std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a)
      if (side[a] != 0) kExit = std::min(kExit, (side[a] > 0 ? b[a] + d : b[a] - d + 1) * slope[a] + offset[a]);
    return kExit >= static_cast<double>(kEnd) ? kEnd + 1 : std::max(k + 1, static_cast<K>(std::max(kExit, 0.0)) + 1);
  }
};

float exponentOf(const SampleLattice& lattice, const RenderSettings& settings) {
  PP5_CHECK_GT(settings.opacityUnitMm, 0.0);
  return static_cast<float>(lattice.step() / settings.opacityUnitMm);
}

}  // namespace

// ---------------------------------------------------------------------------
// Sinks

void SampleCollector::consume(int, std::uint32_t tile, std::span<const RaySample> samples) {
  std::lock_guard<std::mutex> lock(m_);
  if (tile >= tiles_.size()) tiles_.resize(tile + 1);
  tiles_[tile].insert(tiles_[tile].end(), samples.begin(), samples.end());
}

std::vector<RaySample> SampleCollector::samples() const {
  std::lock_guard<std::mutex> lock(m_);
  std::vector<RaySample> out;
  std::size_t n = 0;
  for (const auto& t : tiles_) n += t.size();
  out.reserve(n);
  for (const auto& t : tiles_) out.insert(out.end(), t.begin(), t.end());
  return out;
}

std::size_t SampleCollector::size() const {
  std::lock_guard<std::mutex> lock(m_);
  std::size_t n = 0;
  for (const auto& t : tiles_) n += t.size();
  return n;
}

void SampleCollector::clear() {
  std::lock_guard<std::mutex> lock(m_);
  tiles_.clear();
}

// ---------------------------------------------------------------------------
// Sampling

namespace {

struct TileGrid {
  int size, nx, ny;
  TileGrid(int w, int h, int t) : size(t), nx((w + t - 1) / t), ny((h + t - 1) / t) { PP5_CHECK_GT(t, 0); }
  std::uint32_t count() const { return static_cast<std::uint32_t>(nx) * static_cast<std::uint32_t>(ny); }
};

constexpr int kBrickShift = 3;

// The empty-space brick (EmptySpaceMap::kBrickCells cells a side) of lane
// `lane`'s cell, in a map of `bd` bricks.
inline std::size_t brickOf(const Cells4& c, int lane, const Index3& bd) {
  return static_cast<std::size_t>((static_cast<std::int64_t>(c.i[2][lane] >> kBrickShift) * bd.y +
                                   (c.i[1][lane] >> kBrickShift)) *
                                      bd.x +
                                  (c.i[0][lane] >> kBrickShift));
}
static_assert(EmptySpaceMap::kBrickCells == 1 << kBrickShift);

// The work tiles to sample: all of them (`list` empty, `all` true), or the
// ones options.workTiles selects, in ascending order.
struct TileSelection {
  bool all = true;
  std::vector<std::uint32_t> list;
  TileSelection(const TileGrid& tiles, const std::vector<std::uint8_t>& mask) {
    if (mask.empty()) return;
    PP5_CHECK_EQ(mask.size(), static_cast<std::size_t>(tiles.count()));
    all = false;
    for (std::uint32_t t = 0; t < tiles.count(); ++t)
      if (mask[t] != 0) list.push_back(t);
  }
};

// The smallest k in [a, b] with pred(k) false (b + 1 when there is none), for
// a pred that is true up to some k and false from there on. It gallops up
// from a and then bisects, so a boundary near a costs a call or two.
template <class P>
std::int64_t firstFalse(const P& pred, std::int64_t a, std::int64_t b) {
  if (a > b || !pred(a)) return a;
  std::int64_t lo = a, hi = b + 1;  // pred(lo) is true; hi is false or past b
  for (std::int64_t step = 1; lo + step <= b; step *= 2) {
    if (!pred(lo + step)) {
      hi = lo + step;
      break;
    }
    lo += step;
  }
  while (hi - lo > 1) {
    const std::int64_t m = lo + (hi - lo) / 2;
    (pred(m) ? lo : hi) = m;
  }
  return hi;
}

// SamplerOptions::ownedCells for one call: a conservative clip of a ray to
// the box, and the exact run of the ray's samples whose cell is in it.
class OwnedCells {
public:
  OwnedCells(const Box3& cells, const Index3& cellDims)
      : box_{glm::max(cells.lo, Index3(0)), glm::min(cells.hi, cellDims)} {
    const double inf = std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a) {
      // A cell on a face of the grid also takes the points beyond the face
      // (the cell index is clamped), so the bound goes to infinity there.
      lo_[a] = box_.lo[a] <= 0 ? -inf : static_cast<double>(box_.lo[a]) - kSkipMarginVoxels;
      hi_[a] = box_.hi[a] >= cellDims[a] ? inf : static_cast<double>(box_.hi[a]) + kSkipMarginVoxels;
    }
  }
  const Box3& box() const { return box_; }
  bool empty() const { return box_.empty(); }
  // The points that can have their cell in the box: [lo, hi] in voxel
  // coordinates, per axis.
  double lo(int a) const { return lo_[a]; }
  double hi(int a) const { return hi_[a]; }

  // Narrows [k0, k1], a range of samples of `vr` that holds all of its owned
  // samples in it, to exactly the owned ones; false when there are none. Along
  // the ray each axis' cell is monotone in k (VoxelRay::at rounds
  // monotonically), so the owned samples are one run: the first sample past
  // the box's near faces, up to the last one before its far faces.
  bool exact(const Interpolator& interp, const VoxelRay& vr, std::int64_t& k0, std::int64_t& k1) const {
    if (k0 > k1) return false;
    int side[3];
    for (int a = 0; a < 3; ++a) {
      side[a] = vr.delta[a] > 0.0f ? 1 : (vr.delta[a] < 0.0f ? -1 : 0);
      if (side[a] == 0) {  // one cell along this axis for the whole ray
        const std::int64_t c = interp.cellAxis(vr, static_cast<std::uint32_t>(k0), a);
        if (c < box_.lo[a] || c >= box_.hi[a]) return false;
      }
    }
    auto cell = [&](std::int64_t k, int a) -> std::int64_t {
      return interp.cellAxis(vr, static_cast<std::uint32_t>(k), a);
    };
    // Not yet in the box along some axis / already past it along some axis.
    auto before = [&](std::int64_t k) {
      for (int a = 0; a < 3; ++a)
        if (side[a] > 0 ? cell(k, a) < box_.lo[a] : (side[a] < 0 && cell(k, a) >= box_.hi[a])) return true;
      return false;
    };
    auto past = [&](std::int64_t k) {
      for (int a = 0; a < 3; ++a)
        if (side[a] > 0 ? cell(k, a) >= box_.hi[a] : (side[a] < 0 && cell(k, a) < box_.lo[a])) return true;
      return false;
    };
    const std::int64_t first = firstFalse(before, k0, k1);
    if (first > k1) return false;
    const std::int64_t last = k1 - firstFalse([&](std::int64_t j) { return past(k1 - j); }, 0, k1 - first);
    if (last < first) return false;
    k0 = first;
    k1 = last;
    return true;
  }

private:
  Box3 box_;
  double lo_[3], hi_[3];
};

// The visible samples of a ray's samples k .. kEnd into the stage: jumps
// over empty cubes, and samples four at a time in visible bricks. Inlined
// into each caller, so each gets the code for its own range.
// A sample whose cell is all transparent (`cells`, EmptySpaceMap::cellBits)
// reads no voxels; its prefetch is left out too.
[[gnu::always_inline]] inline void walkVisible(const Interpolator& interp, const VoxelRay& vr, const BrickJump& jump,
                                               const std::uint8_t* dist, const std::uint64_t* cells,
                                               const Index3& bd, std::uint32_t k, const std::uint32_t kEnd,
                                               RayStage& stage) {
  Cells4 c, next;
  Interpolator::Voxels vox{};
  std::int64_t loaded = -1;
  while (k <= kEnd) {
    const int b[3] = {interp.cellAxis(vr, k, 0) >> kBrickShift, interp.cellAxis(vr, k, 1) >> kBrickShift,
                      interp.cellAxis(vr, k, 2) >> kBrickShift};
    const int d = dist[(static_cast<std::int64_t>(b[2]) * bd.y + b[1]) * bd.x + b[0]];
    if (d > 0) {  // in an empty cube: no sample of a visible brick is skipped
      k = jump.next(b, d, k, kEnd);
      continue;
    }
    // A visible brick: sample four at a time until a group starts in an
    // empty brick. The next group is located one ahead, so that its voxels
    // can be fetched while this one is interpolated.
    interp.locate4(vr, k, c);
    for (std::uint32_t g = k;; g += 4) {
      if (g + 4 <= kEnd) {
        interp.locate4(vr, g + 4, next);
        interp.prefetch(next, cells);
      }
      const int lanes = static_cast<int>(std::min<std::uint32_t>(4, kEnd - g + 1));
      for (int l = 0; l < lanes; ++l) {
        const std::int64_t idx = interp.index(c, l);
        if (!EmptySpaceMap::bitSet(cells, idx)) continue;
        float* rgba = stage.slot();
        interp.blendAt(c, l, idx, loaded, vox, rgba);
        if (rgba[3] > 0.0f) stage.commit(g + static_cast<std::uint32_t>(l));
      }
      if (g + 4 > kEnd) {
        k = g + 4;
        break;
      }
      std::swap(c, next);
      if (dist[brickOf(c, 0, bd)] != 0) {
        k = g + 4;
        break;
      }
    }
  }
}

}  // namespace

std::uint32_t workTileCount(int width, int height, int tileSize) {
  PP5_CHECK_GE(width, 0);
  PP5_CHECK_GE(height, 0);
  return TileGrid(width, height, tileSize).count();
}

void sampleAll(const ShadeBuffer& shade, const SampleLattice& lattice, const RenderSettings& settings,
               SampleSink& sink, const EmptySpaceMap* space, const SamplerOptions& options) {
  checkSameGrid(shade.grid(), lattice.grid());
  PP5_CHECK_GT(options.batchSamples, std::size_t{0});
  const int W = lattice.width(), H = lattice.height();
  const TileGrid tiles(W, H, options.tileSize);
  const TileSelection selection(tiles, options.workTiles);
  const std::int64_t workCount =
      selection.all ? static_cast<std::int64_t>(tiles.count()) : static_cast<std::int64_t>(selection.list.size());
  std::optional<OwnedCells> owned;
  if (options.ownedCells) owned.emplace(*options.ownedCells, lattice.grid().dims - Index3(1));
  if (workCount == 0 || (owned && owned->empty())) return;
  EmptySpaceMap own;
  if (!space) {
    own = EmptySpaceMap(shade, settings.threads);
    space = &own;
  }
  checkSameGrid(space->grid(), lattice.grid());
  const Interpolator interp(shade);
  const float e = exponentOf(lattice, settings);
  PP5_CHECK(space->hasCellBits());
  const std::uint8_t* dist = space->distances();
  const std::uint64_t* cells = space->cellBits();
  const Index3 bd = space->brickDims();
  const Box3 occupied = space->occupiedCells();
  if (occupied.empty()) return;
  // A visible sample's cell is in the visible bricks' bounds: where those
  // miss the owned cells, every owned sample is transparent.
  if (owned && owned->box().intersect(occupied).empty()) return;
  // Where a ray is walked: the visible bricks' bounds grown by the margin,
  // and with ownedCells the part of it that can hold an owned cell. (The two
  // boxes meet, so the clip below gives the intersection of their ranges.)
  double clipLo[3], clipHi[3];
  for (int a = 0; a < 3; ++a) {
    clipLo[a] = occupied.lo[a] - kSkipMarginVoxels;
    clipHi[a] = occupied.hi[a] + kSkipMarginVoxels;
    if (owned) {
      clipLo[a] = std::max(clipLo[a], owned->lo(a));
      clipHi[a] = std::min(clipHi[a], owned->hi(a));
    }
  }
  const int nt = static_cast<int>(std::min<std::int64_t>(resolveThreads(settings.threads), workCount));

#pragma omp parallel num_threads(nt)
  {
    Batcher out(sink, omp_get_thread_num(), options.batchSamples);
    RayStage stage(lattice.maxSamples(), e, compositesGreyValues(settings.compositing.front()));
    // This thread's copies: the walk reads them for every ray.
    const OwnedCells* const mine = owned ? &*owned : nullptr;
    const double lo[3] = {clipLo[0], clipLo[1], clipLo[2]}, hi[3] = {clipHi[0], clipHi[1], clipHi[2]};
#pragma omp for schedule(dynamic, 1)
    for (std::int64_t w = 0; w < workCount; ++w) {
      const std::int64_t t = selection.all ? w : selection.list[static_cast<std::size_t>(w)];
      out.startTile(static_cast<std::uint32_t>(t));
      const int x0 = static_cast<int>(t % tiles.nx) * tiles.size, y0 = static_cast<int>(t / tiles.nx) * tiles.size;
      const int x1 = std::min(W, x0 + tiles.size), y1 = std::min(H, y0 + tiles.size);
      for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x) {
          const auto pixel = static_cast<std::uint32_t>(y) * static_cast<std::uint32_t>(W) + static_cast<std::uint32_t>(x);
          const std::uint32_t n = lattice.count(pixel);
          if (n == 0) continue;
          const VoxelRay vr = lattice.voxelRay(pixel);
          // Only the part of the ray inside the visible bricks' bounds (grown
          // by the margin) can have a visible sample; with ownedCells, only
          // its part in the owned box (grown likewise) an owned one.
          double kIn = 0.0, kOut = static_cast<double>(n - 1);
          const BrickJump jump(vr);
          const double* inv = jump.inv;
          for (int a = 0; a < 3; ++a) {
            const double b0 = vr.base[a], dl = vr.delta[a];
            if (dl == 0.0) {
              if (b0 < lo[a] || b0 > hi[a]) kOut = -1.0;
              continue;
            }
            const double t0 = (lo[a] - b0) * inv[a], t1 = (hi[a] - b0) * inv[a];
            kIn = std::max(kIn, std::min(t0, t1));
            kOut = std::min(kOut, std::max(t0, t1));
          }
          if (!(kOut >= kIn)) continue;
          const std::uint32_t k = static_cast<std::uint32_t>(std::ceil(kIn));
          const std::uint32_t kEnd = static_cast<std::uint32_t>(kOut);  // floor: kOut >= 0
          if (k > kEnd) continue;
          if (mine) {  // the clip was conservative: now the exact cells
            std::int64_t k0 = k, k1 = kEnd;
            if (mine->exact(interp, vr, k0, k1))
              walkVisible(interp, vr, jump, dist, cells, bd, static_cast<std::uint32_t>(k0),
                          static_cast<std::uint32_t>(k1), stage);
          } else {
            walkVisible(interp, vr, jump, dist, cells, bd, k, kEnd, stage);
          }
          stage.emit(pixel, out);
        }
      out.flush();
    }
  }
}

#include "rendering/ray_sampler_region.inl"

RaySample sampleAt(const ShadeBuffer& shade, const SampleLattice& lattice, const RenderSettings& settings,
                   std::uint32_t pixel, std::uint32_t k) {
  checkSameGrid(shade.grid(), lattice.grid());
  const Interpolator interp(shade);
  RayStage stage(1, exponentOf(lattice, settings), compositesGreyValues(settings.compositing.front()));
  Cells4 c;
  interp.locate4(lattice.voxelRay(pixel), k, c);
  interp.at(c, 0, stage.slot());
  stage.commit(k);
  SampleCollector one;
  Batcher out(one, 0, 1);
  stage.emit(pixel, out);
  out.flush();
  return one.samples().at(0);
}

}  // namespace pp5::gp
