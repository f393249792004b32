// The pixel processor's ray-sample cache (rendering/ray_cache.hpp) on a 512x512 tile.
// Rays cross a sphere that fills the tile: up to 512 samples at the centre,
// none in the corners (268 on average, 70 M samples). Samples are speckle:
// a quarter empty, the rest at a per-ray opacity level log-uniform in
// [0.002, 0.05] with +-50 % jitter, so some rays reach the termination
// alpha (counter terminated_rays). Default settings (half samples, blocks of 32, early
// termination at 1 - 1/512).
//  - CachePut: storing a full render's samples: a 16-row band through the
//    middle, a ray's samples together as the GP sends them, put over and
//    over; items = samples.
//  - CacheCompositeFull: every block and ray dirty, composite(); threads 1
//    and 0 (every core). What a view change costs after its samples are put.
//  - CacheCompositeOnDemand: compositeFull(mip), a mode that is not live,
//    every core.
//  - CacheIncremental: one frame's dirty slab re-put, a band of 256x512
//    pixels x 16 samples at mid-depth, then composite(), one thread; the
//    argument is the block size (32 is the default).
// Counters: rays and blocks composited per iteration, the cache's memory,
// samples and blocks; CacheIncremental also the least thread CPU time of its
// put and its composite.
// Run: build/microbench/pp5_bench --benchmark_filter=Cache
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <ctime>
#include <memory>
#include <vector>

#include "rendering/ray_cache.hpp"

namespace {

using pp5::RaySample;
using pp5::pp::RayCache;

constexpr int kSize = 512;
double tcpu() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

std::uint64_t mix(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

std::vector<std::uint16_t> sphereCounts() {
  std::vector<std::uint16_t> c(static_cast<std::size_t>(kSize) * kSize);
  for (int y = 0; y < kSize; ++y)
    for (int x = 0; x < kSize; ++x) {
      const double dx = (x + 0.5 - kSize / 2) / (kSize / 2), dy = (y + 0.5 - kSize / 2) / (kSize / 2);
      const double r2 = dx * dx + dy * dy;
      c[static_cast<std::size_t>(y) * kSize + x] = r2 < 1.0 ? static_cast<std::uint16_t>(512.0 * std::sqrt(1.0 - r2)) : 0;
    }
  return c;
}

// Sample k of pixel p in version `salt` (each frame writes a new version).
RaySample speckle(std::uint32_t p, std::uint32_t k, std::uint32_t salt) {
  const std::uint64_t hr = mix(p);
  const float level = 0.002f * std::pow(25.0f, static_cast<float>(hr >> 40) * (1.0f / 16777216.0f));
  const std::uint64_t h = mix((static_cast<std::uint64_t>(p) << 20) ^ (static_cast<std::uint64_t>(k) << 4) ^ salt);
  const float u1 = static_cast<float>(h & 0xffffff) * (1.0f / 16777216.0f);
  const float u2 = static_cast<float>((h >> 24) & 0xffffff) * (1.0f / 16777216.0f);
  const float u3 = static_cast<float>(h >> 48) * (1.0f / 65536.0f);
  const float a = u1 < 0.25f ? 0.0f : std::clamp(level * (0.5f + u2), 0.002f, 0.05f);
  const float grey = 0.3f + 0.7f * u3;
  RaySample s;
  s.pixel = p;
  s.k = k;
  s.a = a;
  s.r = a * grey;
  s.g = a * grey * 0.9f;
  s.b = a * grey * 0.7f;
  return s;
}

// Rows [y0, y0 + rows), every sample.
std::vector<RaySample> bandSamples(const std::vector<std::uint16_t>& counts, int y0, int rows, std::uint32_t salt) {
  std::vector<RaySample> v;
  for (int y = y0; y < y0 + rows; ++y)
    for (int x = 0; x < kSize; ++x) {
      const auto p = static_cast<std::uint32_t>(y * kSize + x);
      for (std::uint32_t k = 0; k < counts[p]; ++k) v.push_back(speckle(p, k, salt));
    }
  return v;
}

// One cache shared by the benchmarks, rebuilt when the block size changes.
struct Shared {
  int blockSize = 0;
  std::vector<std::uint16_t> counts;
  std::unique_ptr<RayCache> cache;
};

RayCache& sharedCache(int blockSize) {
  static Shared s;
  if (!s.cache || s.blockSize != blockSize) {
    s.cache.reset();
    s.counts = sphereCounts();
    pp5::pp::RayCacheSettings settings;
    settings.blockSize = blockSize;
    s.cache = std::make_unique<RayCache>(pp5::TileRect{0, 0, kSize, kSize}, kSize, s.counts, settings,
                                         pp5::pp::CompositeMode::Over, 0);
    for (int y = 0; y < kSize; y += 16) {
      const auto band = bandSamples(s.counts, y, 16, 0);
      s.cache->put(band.data(), band.size());
    }
    s.cache->composite();
    s.blockSize = blockSize;
  }
  return *s.cache;
}

const std::vector<std::uint16_t>& counts() {
  static const std::vector<std::uint16_t> c = sphereCounts();
  return c;
}

void setCounters(benchmark::State& state, const RayCache& c, std::uint64_t rays, std::uint64_t blocks) {
  const double it = static_cast<double>(state.iterations());
  state.counters["rays"] = static_cast<double>(rays) / it;
  state.counters["blocks"] = static_cast<double>(blocks) / it;
  state.counters["MiB"] = static_cast<double>(c.memoryBytes()) / (1024.0 * 1024.0);
  state.counters["cache_samples"] = static_cast<double>(c.sampleCount());
  state.counters["cache_blocks"] = static_cast<double>(c.blockCount());
}

void BM_CachePut(benchmark::State& state) {
  RayCache& c = sharedCache(32);
  const std::vector<RaySample> band = bandSamples(counts(), 240, 16, 0);
  for (auto _ : state) c.put(band.data(), band.size());
  c.composite();
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(band.size()));
}
BENCHMARK(BM_CachePut)->Unit(benchmark::kMillisecond);

void BM_CacheCompositeFull(benchmark::State& state) {
  RayCache& c = sharedCache(32);
  c.setThreads(static_cast<int>(state.range(0)));
  std::uint64_t rays = 0, blocks = 0;
  for (auto _ : state) {
    state.PauseTiming();
    c.invalidate();
    state.ResumeTiming();
    const auto st = c.composite();
    rays += st.rays;
    blocks += st.blocks;
  }
  setCounters(state, c, rays, blocks);
  std::size_t opaque = 0;
  for (std::size_t i = 3; i < c.image().rgba.size(); i += 4) opaque += c.image().rgba[i] >= 1.0f - 1.0f / 512.0f;
  state.counters["terminated_rays"] = static_cast<double>(opaque);
  c.setThreads(0);
}
BENCHMARK(BM_CacheCompositeFull)->ArgName("threads")->Arg(1)->Arg(0)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_CacheCompositeOnDemand(benchmark::State& state) {
  RayCache& c = sharedCache(32);
  for (auto _ : state) benchmark::DoNotOptimize(c.compositeFull(pp5::pp::CompositeMode::Mip));
  setCounters(state, c, 0, 0);
}
BENCHMARK(BM_CacheCompositeOnDemand)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_CacheIncremental(benchmark::State& state) {
  RayCache& c = sharedCache(static_cast<int>(state.range(0)));
  c.setThreads(1);
  const auto& n = counts();
  // The same slab in two versions, alternated, so every put is a change.
  std::vector<RaySample> slab[2];
  for (std::uint32_t v = 0; v < 2; ++v)
    for (int y = 0; y < kSize; ++y)
      for (int x = kSize / 4; x < 3 * kSize / 4; ++x) {
        const auto p = static_cast<std::uint32_t>(y * kSize + x);
        const int k0 = std::max(0, n[p] / 2 - 8), k1 = std::min<int>(n[p], k0 + 16);
        for (int k = k0; k < k1; ++k) slab[v].push_back(speckle(p, static_cast<std::uint32_t>(k), v + 1));
      }
  std::uint64_t rays = 0, blocks = 0, i = 0;
  double tput = 1e30, tcomp = 1e30;
  for (auto _ : state) {
    const auto& s = slab[i++ & 1];
    auto t0 = tcpu();
    c.put(s.data(), s.size());
    auto t1 = tcpu();
    const auto st = c.composite();
    auto t2 = tcpu();
    tput = std::min(tput, t1 - t0);
    tcomp = std::min(tcomp, t2 - t1);
    rays += st.rays;
    blocks += st.blocks;
  }
  setCounters(state, c, rays, blocks);
  state.counters["samples"] = static_cast<double>(slab[0].size());
  // The two halves apart, as the least thread CPU time over the iterations:
  // the machine may be shared, and the least is what the code costs.
  state.counters["put_cpu_ms"] = tput;
  state.counters["composite_cpu_ms"] = tcomp;
  c.setThreads(0);
}
BENCHMARK(BM_CacheIncremental)->ArgName("block")->Arg(32)->Arg(8)->Arg(16)->Arg(64)->Arg(128)->Unit(benchmark::kMillisecond);

}  // namespace
