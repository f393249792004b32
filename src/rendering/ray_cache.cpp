#include "rendering/ray_cache.hpp"

#include <immintrin.h>
#include <omp.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <climits>
#include <cmath>

#include <fmt/format.h>

#include "core/error.hpp"
#include "rendering/composite_kernels.hpp"
#include "core/half_float.hpp"
#include "core/threads.hpp"

namespace pp5::pp {

namespace {

using namespace composite;

// Below this many rays (pages of samples) a parallel region costs more than it saves.
constexpr std::size_t kMinParallelRays = 512;
constexpr std::size_t kMinParallelPages = 16384;

}  // namespace

// ---------------------------------------------------------------------------
// Storing samples.

namespace {

// Whether a stored sample (4 values) has a bit set: a page that only zeros
// were written to stays all zero and needs no clearing (RayCache::reset).
template <class T>
[[gnu::always_inline]] inline bool storedNonzero(const T* d) {
  if constexpr (sizeof(T) == 4) {
    std::uint64_t a, b;
    std::memcpy(&a, d, 8);
    std::memcpy(&b, d + 2, 8);
    return (a | b) != 0;
  } else if constexpr (sizeof(T) == 2) {
    std::uint64_t a;
    std::memcpy(&a, d, 8);
    return a != 0;
  } else {
    std::uint32_t a;
    std::memcpy(&a, d, 4);
    return a != 0;
  }
}

struct EncodeFloat {
  [[gnu::always_inline]] static inline void encode(const RaySample& s, float* d) { std::memcpy(d, &s.r, 16); }
};
struct EncodeHalf {
  [[gnu::always_inline]] static inline void encode(const RaySample& s, std::uint16_t* d) {
    d[0] = floatToHalf(s.r);
    d[1] = floatToHalf(s.g);
    d[2] = floatToHalf(s.b);
    d[3] = floatToHalf(s.a);
  }
};
struct EncodeHalfF16c {
  __attribute__((target("avx,f16c"))) static inline void encode(const RaySample& s, std::uint16_t* d) {
    const __m128i h = _mm_cvtps_ph(_mm_loadu_ps(&s.r), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    _mm_storel_epi64(reinterpret_cast<__m128i*>(d), h);
  }
};
struct EncodeRgba8 {
  [[gnu::always_inline]] static inline void encode(const RaySample& s, std::uint8_t* d) {
    d[0] = toU8(s.r);
    d[1] = toU8(s.g);
    d[2] = toU8(s.b);
    d[3] = toU8(s.a);
  }
};

// Calls fn.template operator()<F, M>() with the format and mode as template
// arguments: the kernels are specialised per format and mode, and dispatched
// once per call.
template <class Fn>
void forFormatAndMode(SampleFormat format, CompositeMode mode, Fn&& fn) {
  auto withMode = [&]<SampleFormat F>() {
    switch (mode) {
      case CompositeMode::Over: fn.template operator()<F, CompositeMode::Over>(); break;
      case CompositeMode::Additive: fn.template operator()<F, CompositeMode::Additive>(); break;
      case CompositeMode::Mip: fn.template operator()<F, CompositeMode::Mip>(); break;
    }
  };
  switch (format) {
    case SampleFormat::Rgba8: withMode.template operator()<SampleFormat::Rgba8>(); break;
    case SampleFormat::Half: withMode.template operator()<SampleFormat::Half>(); break;
    case SampleFormat::Float: withMode.template operator()<SampleFormat::Float>(); break;
  }
}

}  // namespace

struct RayCacheAccess {
  // `list`: where a ray newly dirty is listed. Concurrent: other threads put
  // other rays at the same time, so the touched-page flags, which rays share,
  // are written atomically.
  template <class Enc, bool Concurrent, class T>
  static inline void putLoop(RayCache& c, T* store, const RaySample* samples, std::size_t n,
                             std::vector<std::uint32_t>& list) {
    // A ray's samples usually arrive together: map a pixel to its ray once.
    std::uint32_t lastPixel = 0;
    RayCache::Ray* ray = nullptr;
    std::uint32_t local = 0;
    const auto w = static_cast<std::uint32_t>(c.imageWidth_);
    const TileRect& t = c.tile_;
    std::uint8_t* dirty = c.dirty_.data();
    std::uint8_t* touched = c.touched_.data();
    const int shift = c.blockShift_;
    // The tile-local ray of a pixel, or -1 outside the tile.
    auto localOf = [&](std::uint32_t pixel) -> std::int64_t {
      const std::uint32_t tx = pixel % w - static_cast<std::uint32_t>(t.x0);
      const std::uint32_t ty = pixel / w - static_cast<std::uint32_t>(t.y0);
      if (tx >= static_cast<std::uint32_t>(t.width) || ty >= static_cast<std::uint32_t>(t.height)) return -1;
      return static_cast<std::int64_t>(ty) * t.width + tx;
    };
    // Writes miss: prefetch the ray record kFar samples ahead, then the
    // sample's line and dirty flag kNear ahead, once per ray met.
    constexpr std::size_t kNear = 32, kFar = 64;
    std::uint32_t farPixel = 0xffffffffu, nearPixel = 0xffffffffu;
    for (std::size_t i = 0; i < n; ++i) {
      if (i + kFar < n && samples[i + kFar].pixel != farPixel) {
        farPixel = samples[i + kFar].pixel;
        const std::int64_t l = localOf(farPixel);
        if (l >= 0) __builtin_prefetch(&c.rays_[static_cast<std::size_t>(l)]);
      }
      if (i + kNear < n && samples[i + kNear].pixel != nearPixel) {
        const RaySample& a = samples[i + kNear];
        nearPixel = a.pixel;
        const std::int64_t l = localOf(nearPixel);
        if (l >= 0) {
          const RayCache::Ray& r = c.rays_[static_cast<std::size_t>(l)];
          __builtin_prefetch(store + 4 * r.at(a.k, shift), 1);
          __builtin_prefetch(dirty + r.block + (a.k >> shift), 1);
        }
      }
      const RaySample& s = samples[i];
      if (!ray || s.pixel != lastPixel) {
        const std::int64_t l = localOf(s.pixel);
        if (l < 0) outsideTile(c, s);
        local = static_cast<std::uint32_t>(l);
        ray = &c.rays_[local];
        lastPixel = s.pixel;
      }
      if (s.k >= ray->count) beyondRay(s, ray->count);
      const std::uint64_t at = ray->at(s.k, shift);
      Enc::encode(s, store + 4 * at);
      if constexpr (Concurrent) {
        if (storedNonzero(store + 4 * at)) {
          const std::atomic_ref<std::uint8_t> page(touched[at >> RayCache::kPageShift]);
          if (!page.load(std::memory_order_relaxed)) page.store(1, std::memory_order_relaxed);
        }
      } else {
        touched[at >> RayCache::kPageShift] |= static_cast<std::uint8_t>(storedNonzero(store + 4 * at));
      }
      const std::uint32_t b = s.k >> shift;
      // A block behind the termination point cannot change the pixel: it is
      // marked but not listed, and waits until a change in front makes the
      // walk reach it.
      dirty[ray->block + b] = kBlockDirty;
      if (b < ray->end) {
        const auto b16 = static_cast<std::uint16_t>(b);
        if (!ray->listed) {
          ray->listed = 1;
          ray->firstDirty = ray->lastDirty = b16;
          list.push_back(local);
        } else {
          ray->firstDirty = std::min(ray->firstDirty, b16);
          ray->lastDirty = std::max(ray->lastDirty, b16);
        }
      }
    }
    if constexpr (Concurrent) std::atomic_ref<std::uint64_t>(c.counters_.samplesPut).fetch_add(n, std::memory_order_relaxed);
    else c.counters_.samplesPut += n;
  }

  [[noreturn]] static void outsideTile(const RayCache& c, const RaySample& s) {
    const auto w = static_cast<std::uint32_t>(c.imageWidth_);
    throw InvariantError(fmt::format("RayCache::put: a sample of pixel ({}, {}) lies outside the tile at ({}, {}) of "
                                     "{} x {}",
                                     s.pixel % w, s.pixel / w, c.tile_.x0, c.tile_.y0, c.tile_.width, c.tile_.height));
  }
  [[noreturn]] static void beyondRay(const RaySample& s, unsigned count) {
    throw InvariantError(
        fmt::format("RayCache::put: sample k = {} of pixel {} beyond its ray's {} samples", s.k, s.pixel, count));
  }

  // flatten: the loop and its encoder are compiled here, for this target.
  template <bool Concurrent>
  __attribute__((target("avx,f16c"), flatten)) static void putHalfF16c(RayCache& c, const RaySample* s, std::size_t n,
                                                                      std::vector<std::uint32_t>& list) {
    putLoop<EncodeHalfF16c, Concurrent>(c, c.samples16_.data(), s, n, list);
  }
  template <bool Concurrent>
  static void put(RayCache& c, const RaySample* s, std::size_t n, std::vector<std::uint32_t>& list) {
    switch (c.format_) {
      case SampleFormat::Rgba8: putLoop<EncodeRgba8, Concurrent>(c, c.samples8_.data(), s, n, list); break;
      case SampleFormat::Half:
        if (halfConversionUsesF16c()) putHalfF16c<Concurrent>(c, s, n, list);
        else putLoop<EncodeHalf, Concurrent>(c, c.samples16_.data(), s, n, list);
        break;
      case SampleFormat::Float: putLoop<EncodeFloat, Concurrent>(c, c.samples32_.data(), s, n, list); break;
    }
  }
};

// ---------------------------------------------------------------------------

RayCache::RayCache(const TileRect& tile, int imageWidth, std::span<const std::uint16_t> sampleCounts,
                   const RayCacheSettings& settings, CompositeMode live, int threads)
    : tile_(tile), imageWidth_(imageWidth), live_(live), threads_(threads) {
  settings.validate();
  format_ = settings.format;
  blockSize_ = settings.blockSize;
  blockShift_ = std::countr_zero(static_cast<unsigned>(blockSize_));
  transmittanceLimit_ = settings.earlyTermination ? static_cast<float>(1.0 - settings.terminationAlpha) : -1.0f;
  additiveScale_ = static_cast<float>(settings.additiveScale);
  PP5_CHECK(!tile.empty());
  PP5_CHECK_GE(tile.x0, 0);
  PP5_CHECK_GE(tile.y0, 0);
  PP5_CHECK_LE(static_cast<long>(tile.x0) + tile.width, static_cast<long>(imageWidth));
  reset(sampleCounts);
}

void RayCache::setValueWindow(double lo, double hi) {
  if (!(hi > lo) || !(lo >= 0.0) || !std::isfinite(hi))
    throw InputError(fmt::format("render.value_window = [{}, {}]: give 0 <= black < white (grey levels)", lo, hi));
  const auto newLo = static_cast<float>(lo), newInvWidth = static_cast<float>(1.0 / (hi - lo));
  if (newLo == valueLo_ && newInvWidth == valueInvWidth_) return;
  valueLo_ = newLo;
  valueInvWidth_ = newInvWidth;
  // Only the grey-value modes read the window; "over" keeps its partials (a
  // later change to MIP or additive recomposites everything anyway), and an
  // unchanged window keeps them too. Recompositing a whole tile on every call
  // made the first image after every control change a full composite (issue
  // 17's bench latency). A MIP or additive cache just reset still recomposites
  // when the window does change, which costs a pass over zeros.
  if (compositesGreyValues(live_)) invalidate();
}

void RayCache::layOut(std::span<const std::uint16_t> sampleCounts) {
  const std::size_t w = static_cast<std::size_t>(tile_.width), h = static_cast<std::size_t>(tile_.height);
  const std::size_t n = w * h;
  PP5_CHECK_EQ(sampleCounts.size(), n);
  // A group is gx x gy rays whose block row is about a page. Groups are cut
  // from the columns and rows that hold rays with samples (a strided view's
  // others have none), so that neighbours on the lattice share a group.
  constexpr std::size_t kGroupBytes = 4096;
  const std::size_t blockBytes = static_cast<std::size_t>(blockSize_) * sampleFormatBytes(format_);
  const std::size_t rays = std::max<std::size_t>(1, kGroupBytes / blockBytes);  // a power of two
  const std::size_t gx = std::size_t{1} << ((std::countr_zero(rays) + 1) / 2), gy = rays / gx;
  // Each column's and row's group along its axis, counting only those that
  // hold a ray with samples; the others are never asked.
  std::vector<std::uint8_t> colUsed(w, 0), rowUsed(h, 0);
  for (std::size_t y = 0; y < h; ++y)
    for (std::size_t x = 0; x < w; ++x)
      if (sampleCounts[y * w + x] > 0) colUsed[x] = rowUsed[y] = 1;
  std::vector<std::size_t> colGroup(w, 0), rowGroup(h, 0);
  std::size_t cols = 0, rowsUsed = 0;
  for (std::size_t x = 0; x < w; ++x)
    if (colUsed[x]) colGroup[x] = cols++ / gx;
  for (std::size_t y = 0; y < h; ++y)
    if (rowUsed[y]) rowGroup[y] = rowsUsed++ / gy;
  const std::size_t ngx = (cols + gx - 1) / gx, ngy = (rowsUsed + gy - 1) / gy;
  // Each group's rays and its deepest ray's blocks, from the counts alone
  // (small and read in order), so that the rays are written in one pass.
  std::vector<std::uint64_t> members(ngx * ngy, 0), depth(ngx * ngy, 0);
  auto groupOf = [&](std::size_t x, std::size_t y) { return rowGroup[y] * ngx + colGroup[x]; };
  for (std::size_t y = 0; y < h; ++y) {
    if (!rowUsed[y]) continue;
    for (std::size_t x = 0; x < w; ++x) {
      const std::uint16_t count = sampleCounts[y * w + x];
      if (count == 0) continue;
      const std::size_t g = groupOf(x, y);
      ++members[g];
      depth[g] = std::max<std::uint64_t>(depth[g], blocksOf(count));
    }
  }
  // Groups one after the other, row by row; `next`: each group's next
  // ray's first sample as the rays are laid out, row by row.
  std::vector<std::uint64_t> next(ngx * ngy, 0);
  std::uint64_t total = 0;
  for (std::size_t g = 0; g < next.size(); ++g) {
    next[g] = total;
    total += members[g] * depth[g] * static_cast<std::uint64_t>(blockSize_);
  }
  storageSamples_ = total;
  sampleTotal_ = 0;
  blockTotal_ = 0;
  rays_.resize(n);
  for (std::size_t y = 0, i = 0; y < h; ++y)
    for (std::size_t x = 0; x < w; ++x, ++i) {
      Ray& r = rays_[i];
      r = Ray{};
      r.block = static_cast<std::uint32_t>(blockTotal_);
      r.count = sampleCounts[i];
      // An untouched ray is transparent; "over" never reaches the limit on it.
      r.end = blocksOf(r.count);
      r.stride = static_cast<std::uint16_t>(blockSize_);
      sampleTotal_ += r.count;
      blockTotal_ += r.end;
      // A ray records its first block in 32 bits.
      PP5_CHECK_LE(blockTotal_, std::uint64_t{0xffffffffu});
      if (r.count == 0) continue;
      const std::size_t g = groupOf(x, y);
      r.sample = next[g];
      next[g] += static_cast<std::uint64_t>(blockSize_);
      r.stride = static_cast<std::uint16_t>(members[g] * static_cast<std::uint64_t>(blockSize_));
    }
}

void RayCache::reset(std::span<const std::uint16_t> sampleCounts) {
  layOut(sampleCounts);
  // The storage is kept, and is all zero but for the pages put() wrote:
  // zeroing those costs what the last view wrote, not the cache's size; a
  // larger view gets new zeroed address space (ZeroedArray).
  zeroTouched();
  const std::size_t values = 4 * static_cast<std::size_t>(storageSamples_);
  switch (format_) {
    case SampleFormat::Rgba8: samples8_.resize(values); break;
    case SampleFormat::Half: samples16_.resize(values); break;
    case SampleFormat::Float: samples32_.resize(values); break;
  }
  touched_.assign((storageSamples_ >> kPageShift) + 1, 0);
  // A block of transparent samples composites to the identity exactly, so
  // blocks start transparent (no partial stored: the storage only grows, and
  // what it holds is written before it is read) and nothing is dirty until
  // samples arrive.
  if (partials_.size() < blockTotal_) partials_.resize(blockTotal_);
  dirty_.assign(blockTotal_, kBlockTransparent);
  dirtyRays_.clear();
  for (auto& l : laneRays_) l.clear();
  image_.width = tile_.width;
  image_.height = tile_.height;
  image_.rgba.assign(4 * rays_.size(), 0.0f);
}

void RayCache::put(const RaySample* samples, std::size_t n) { RayCacheAccess::put<false>(*this, samples, n, dirtyRays_); }

void RayCache::setPutLanes(int lanes) {
  PP5_CHECK_GE(lanes, 1);
  laneRays_.resize(static_cast<std::size_t>(lanes));
}

void RayCache::put(int lane, const RaySample* samples, std::size_t n) {
  PP5_CHECK(lane >= 0 && static_cast<std::size_t>(lane) < laneRays_.size());
  RayCacheAccess::put<true>(*this, samples, n, laneRays_[static_cast<std::size_t>(lane)]);
}

void RayCache::mergeLanes() {
  for (std::vector<std::uint32_t>& l : laneRays_) {
    dirtyRays_.insert(dirtyRays_.end(), l.begin(), l.end());
    l.clear();
  }
}

template <SampleFormat F, CompositeMode M>
CompositeStats RayCache::compositeDirty() {
  using T = typename Storage<F>::T;
  const T* store;
  if constexpr (F == SampleFormat::Rgba8) store = samples8_.data();
  else if constexpr (F == SampleFormat::Half) store = samples16_.data();
  else store = samples32_.data();

  CompositeStats st;
  mergeLanes();
  const std::size_t nd = dirtyRays_.size();
  ++counters_.composites;
  if (nd == 0) return st;

  const int nt = resolveThreads(threads_);
  const std::uint32_t tw = static_cast<std::uint32_t>(tile_.width);
  std::uint64_t blocks = 0;
  int xmin = INT_MAX, ymin = INT_MAX, xmax = INT_MIN, ymax = INT_MIN;
  Ray* rays = rays_.data();
  Partial* partials = partials_.data();
  std::uint8_t* dirty = dirty_.data();
  float* image = image_.rgba.data();
  const std::uint32_t* list = dirtyRays_.data();
  const int bs = blockSize_, shift = blockShift_;
  const float limit = transmittanceLimit_;
  const Finish fin{additiveScale_, valueLo_, valueInvWidth_};

  // Rays ahead to prefetch: enough to cover a miss to memory per ray.
  constexpr std::size_t kAhead = 8;
  // Prefetch at most this much of a ray's dirty samples; the hardware
  // prefetcher follows a longer run.
  constexpr std::size_t kPrefetchBytes = 1024;
  constexpr std::size_t kLine = 64;
  const std::size_t sampleBytes = 4 * sizeof(T);

#pragma omp parallel num_threads(nt) if (nt > 1 && nd >= kMinParallelRays) \
    reduction(+ : blocks) reduction(min : xmin, ymin) reduction(max : xmax, ymax)
  {
    alignas(64) float scratch[4 * kMaxBlockSize];
#pragma omp for schedule(dynamic, 256)
    for (std::size_t i = 0; i < nd; ++i) {
      if (i + 2 * kAhead < nd) __builtin_prefetch(rays + list[i + 2 * kAhead]);
      if (i + kAhead < nd) {
        const Ray& a = rays[list[i + kAhead]];
        // The dirty blocks' samples, block by block (Ray::at).
        std::size_t left = kPrefetchBytes;
        for (std::uint32_t b = a.firstDirty; b <= a.lastDirty && left > 0; ++b) {
          const std::uint32_t k = b << shift;
          const char* p = reinterpret_cast<const char*>(store + 4 * a.at(k, shift));
          const std::size_t bytes =
              std::min<std::size_t>(std::min<std::size_t>(a.count - k, static_cast<std::size_t>(bs)) * sampleBytes, left);
          for (std::size_t o = 0; o < bytes; o += kLine) __builtin_prefetch(p + o);
          left -= bytes;
        }
        __builtin_prefetch(partials + a.block);
        __builtin_prefetch(dirty + a.block);
      }
      const std::uint32_t local = list[i];
      Ray& r = rays[local];
      std::uint32_t end = 0;
      const Partial acc = walkRay<F, M>(RayView{r.sample, r.block, r.count, r.stride}, store, bs, shift, partials,
                                        dirty, limit, end, blocks, scratch);
      r.end = static_cast<std::uint16_t>(end);
      finish<M>(acc, fin, image + 4 * static_cast<std::size_t>(local));
      r.listed = 0;
      const int x = static_cast<int>(local % tw), y = static_cast<int>(local / tw);
      xmin = std::min(xmin, x);
      xmax = std::max(xmax, x);
      ymin = std::min(ymin, y);
      ymax = std::max(ymax, y);
    }
  }
  dirtyRays_.clear();
  st.rays = nd;
  st.blocks = blocks;
  st.changed = TileRect{xmin, ymin, xmax - xmin + 1, ymax - ymin + 1};
  counters_.raysComposited += nd;
  counters_.blocksComposited += blocks;
  return st;
}

CompositeStats RayCache::composite() {
  CompositeStats st;
  forFormatAndMode(format_, live_, [&]<SampleFormat F, CompositeMode M>() { st = compositeDirty<F, M>(); });
  if (stride_ > 1 && !st.changed.empty()) st.changed = fillBlocks(image_, st.changed);
  return st;
}

void RayCache::setPixelStride(int stride) {
  PP5_CHECK_GE(stride, 1);
  stride_ = stride;
  // Per axis, the tile-local column (row) whose pixel each one shows: its
  // strided pixel to the left (above), or the tile's first strided one for
  // those before it; -1 when the tile has none.
  auto sources = [stride](int origin, int size) {
    std::vector<int> src(static_cast<std::size_t>(size));
    const int first = (stride - origin % stride) % stride;  // the first strided one, tile-local
    for (int i = 0; i < size; ++i) {
      const int g = origin + i;
      const int own = g - g % stride - origin;
      src[static_cast<std::size_t>(i)] = own >= 0 ? own : (first < size ? first : -1);
    }
    return src;
  };
  srcX_ = sources(tile_.x0, tile_.width);
  srcY_ = sources(tile_.y0, tile_.height);
}

TileRect RayCache::fillBlocks(TileImage& im, const TileRect& changed) const {
  // The pixels that show a strided pixel of `changed` are one run per axis.
  auto span = [](const std::vector<int>& src, int lo, int hi, int& a, int& b) {
    a = INT_MAX;
    b = -1;
    for (int i = 0; i < static_cast<int>(src.size()); ++i)
      if (src[static_cast<std::size_t>(i)] >= lo && src[static_cast<std::size_t>(i)] <= hi) {
        a = std::min(a, i);
        b = i;
      }
  };
  int x0, x1, y0, y1;
  span(srcX_, changed.x0, changed.x0 + changed.width - 1, x0, x1);
  span(srcY_, changed.y0, changed.y0 + changed.height - 1, y0, y1);
  if (x1 < x0 || y1 < y0) return changed;
  float* px = im.rgba.data();
  const auto w = static_cast<std::size_t>(im.width);
  for (int y = y0; y <= y1; ++y) {
    const int sy = srcY_[static_cast<std::size_t>(y)];
    for (int x = x0; x <= x1; ++x) {
      const int sx = srcX_[static_cast<std::size_t>(x)];
      if (sx == x && sy == y) continue;  // a strided pixel: a source
      std::memcpy(px + 4 * (static_cast<std::size_t>(y) * w + x), px + 4 * (static_cast<std::size_t>(sy) * w + sx),
                  4 * sizeof(float));
    }
  }
  return TileRect{x0, y0, x1 - x0 + 1, y1 - y0 + 1};
}

template <SampleFormat F, CompositeMode M>
void RayCache::compositeAll(TileImage& out) const {
  using T = typename Storage<F>::T;
  const T* store;
  if constexpr (F == SampleFormat::Rgba8) store = samples8_.data();
  else if constexpr (F == SampleFormat::Half) store = samples16_.data();
  else store = samples32_.data();

  const int nt = resolveThreads(threads_);
  const int w = tile_.width, h = tile_.height;
  const int bs = blockSize_, shift = blockShift_;
  const float limit = transmittanceLimit_;
  const Finish fin{additiveScale_, valueLo_, valueInvWidth_};
  const Ray* rays = rays_.data();
  float* image = out.rgba.data();
#pragma omp parallel num_threads(nt) if (nt > 1 && rays_.size() >= kMinParallelRays)
  {
    alignas(64) float scratch[4 * kMaxBlockSize];
#pragma omp for schedule(dynamic, 1)
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const std::size_t local = static_cast<std::size_t>(y) * w + x;
        const Ray& r = rays[local];
        std::uint32_t end = 0;
        std::uint64_t computed = 0;
        const Partial acc = walkRay<F, M>(RayView{r.sample, r.block, r.count, r.stride}, store, bs, shift, nullptr,
                                          nullptr, limit, end, computed, scratch);
        finish<M>(acc, fin, image + 4 * local);
      }
    }
  }
}

TileImage RayCache::compositeFull(CompositeMode mode) const {
  TileImage out;
  out.width = tile_.width;
  out.height = tile_.height;
  out.rgba.assign(4 * rays_.size(), 0.0f);
  forFormatAndMode(format_, mode, [&]<SampleFormat F, CompositeMode M>() { compositeAll<F, M>(out); });
  if (stride_ > 1 && !rays_.empty()) fillBlocks(out, TileRect{0, 0, tile_.width, tile_.height});
  return out;
}

void RayCache::zeroTouched() {
  const std::size_t pages = touched_.size();
  const int nt = resolveThreads(threads_);
  auto zero = [&](auto& store) {
    const std::size_t perPage = 4 * (std::size_t{1} << kPageShift);
    // A new view after a full one rewrites tens of MB; the pages are disjoint.
#pragma omp parallel for num_threads(nt) if (nt > 1 && pages >= kMinParallelPages) schedule(static, 4096)
    for (std::size_t p = 0; p < pages; ++p) {
      if (!touched_[p]) continue;
      const std::size_t begin = p * perPage;
      const std::size_t end = std::min(store.size(), begin + perPage);
      if (begin < end) std::memset(store.data() + begin, 0, (end - begin) * sizeof(*store.data()));
    }
  };
  switch (format_) {
    case SampleFormat::Rgba8: zero(samples8_); break;
    case SampleFormat::Half: zero(samples16_); break;
    case SampleFormat::Float: zero(samples32_); break;
  }
  std::fill(touched_.begin(), touched_.end(), std::uint8_t{0});
}

void RayCache::clear() {
  zeroTouched();
  std::fill(dirty_.begin(), dirty_.end(), kBlockTransparent);
  for (Ray& r : rays_) {
    r.listed = 0;
    r.end = blocksOf(r.count);
  }
  dirtyRays_.clear();
  for (auto& l : laneRays_) l.clear();
  std::fill(image_.rgba.begin(), image_.rgba.end(), 0.0f);
}

void RayCache::invalidate() {
  for (auto& l : laneRays_) l.clear();
  std::fill(dirty_.begin(), dirty_.end(), kBlockDirty);
  dirtyRays_.resize(rays_.size());
  for (std::size_t i = 0; i < rays_.size(); ++i) {
    Ray& r = rays_[i];
    r.listed = 1;
    r.firstDirty = 0;
    r.lastDirty = static_cast<std::uint16_t>(std::max(1, static_cast<int>(blocksOf(r.count))) - 1);
    dirtyRays_[i] = static_cast<std::uint32_t>(i);
  }
}

}  // namespace pp5::pp
