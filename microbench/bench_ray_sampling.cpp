// Ray-sampling on the default view: a 256^3 grid of 0.8 mm voxels shown at
// 512x512 (perspective, render defaults), step 0.4 mm, at most 512 samples a
// ray. The shade buffer is a blob phantom: a large ellipsoid of semi-
// transparent, textured tissue and a small opaque sphere, transparent around
// them, as a transfer function leaves a scan.
// Targets (issue 4): incremental update (shade + sample + composite of one
// frame) <= 33 ms on one core; full re-render <= 150 ms on two cores.
//  - SampleAll: every visible sample after a view change (threads 1, 0 = all).
//  - SampleLattice: building the lattice for the view.
//  - EmptySpaceMapBuild: the empty-space map of the whole shade buffer.
//  - DBufferAndSampleRegion: one reconstructed frame (256x256 pixels of 0.38 x
//    0.76 mm, the default tent reach 2 x 1 x 3 mm, + 1 voxel of gradient
//    reach for shading) swept along x: stencil boxes, D-buffer, sampleRegion,
//    one thread. region 0: the frame's exact voxel box; region 1: the 16-voxel
//    bricks the reconstruction reports for it (addOrientedSlab).
// Run: build/microbench/pp5_bench --benchmark_filter='Sample|DBuffer|EmptySpace'
#include <benchmark/benchmark.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include "core/grid.hpp"
#include "core/render_settings.hpp"
#include "rendering/dbuffer.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/ray_sampler.hpp"
#include "core/sample_lattice.hpp"
#include "formats/sample_runs.hpp"
#include "rendering/shade_buffer.hpp"

#include "bench_grid.hpp"

namespace {

using pp5::bench::benchGrid;

using pp5::Grid;
using pp5::Index3;
using pp5::Vec3;
namespace gp = pp5::gp;
using pp5::SampleLattice;

constexpr double kFrameWidthMm = 256 * 0.38, kFrameDepthMm = 256 * 0.76;
const Vec3 kTentReachMm(2.0, 1.0, 3.0);  // lateral, axial, elevational

std::uint32_t hash3(std::int64_t i, std::int64_t j, std::int64_t k) {
  std::uint32_t h = static_cast<std::uint32_t>(i) * 73856093u ^ static_cast<std::uint32_t>(j) * 19349663u ^
                    static_cast<std::uint32_t>(k) * 83492791u;
  h ^= h >> 13;
  h *= 0x5bd1e995u;
  h ^= h >> 15;
  return h;
}

struct Scene {
  Grid grid = benchGrid();
  pp5::RenderSettings settings;
  gp::ShadeBuffer shade{grid};
  std::unique_ptr<gp::EmptySpaceMap> space;
  std::unique_ptr<SampleLattice> lattice;

  Scene() {
    for (std::int64_t k = 0; k < grid.dims.z; ++k)
      for (std::int64_t j = 0; j < grid.dims.y; ++j)
        for (std::int64_t i = 0; i < grid.dims.x; ++i) {
          const Vec3 p = grid.voxelToWorld(Vec3(i, j, k));
          const Vec3 e = p / Vec3(70.0, 55.0, 80.0);
          const double r2 = glm::dot(e, e);
          const double bone = glm::length(p - Vec3(30.0, -20.0, 35.0));
          gp::ShadeVoxel& v = shade.at(grid.linear(i, j, k));
          if (bone < 15.0) {
            v = {200, 190, 170, 250};
          } else if (r2 < 1.0) {
            // Smooth texture and speckle; about a fifth of the voxels transparent.
            const double tex = 0.5 + 0.25 * std::sin(p.x * 0.21) * std::sin(p.y * 0.17) + 0.25 * std::sin(p.z * 0.13);
            const std::uint32_t h = hash3(i, j, k);
            if (h % 5 == 0) continue;
            const auto a = static_cast<std::uint8_t>(std::clamp(20.0 + 100.0 * tex + (h >> 24) % 30, 0.0, 255.0));
            v = {static_cast<std::uint8_t>(a * 9 / 10), static_cast<std::uint8_t>(a * 7 / 10),
                 static_cast<std::uint8_t>(a * 6 / 10), a};
          }
        }
    space = std::make_unique<gp::EmptySpaceMap>(shade, 0);
    lattice = std::make_unique<SampleLattice>(settings, grid);
  }
};

const Scene& scene() {
  static const Scene s;
  return s;
}

// Per-thread counters on their own cache lines; reading each sample's alpha
// stands for a consumer that touches the batch.
class CountingSink final : public gp::SampleSink {
public:
  void consume(int thread, std::uint32_t, std::span<const pp5::RaySample> samples) override {
    Slot& s = slots_[static_cast<std::size_t>(thread) % slots_.size()];
    float a = 0.0f;
    std::uint64_t visible = 0;
    for (const auto& x : samples) {
      a += x.a;
      visible += x.a > 0.0f;
    }
    s.samples += samples.size();
    s.visible += visible;
    s.alpha += a;
  }
  std::uint64_t samples() const {
    std::uint64_t n = 0;
    for (const auto& s : slots_) n += s.samples;
    return n;
  }
  std::uint64_t visible() const {
    std::uint64_t n = 0;
    for (const auto& s : slots_) n += s.visible;
    return n;
  }
  void reset() {
    for (auto& s : slots_) s = {};
  }

private:
  struct alignas(64) Slot {
    std::uint64_t samples = 0, visible = 0;
    double alpha = 0.0;
  };
  std::array<Slot, 64> slots_{};
};

void BM_SampleAll(benchmark::State& state) {
  const Scene& sc = scene();
  pp5::RenderSettings s = sc.settings;
  s.threads = static_cast<int>(state.range(0));
  CountingSink sink;
  std::uint64_t n = 0;
  for (auto _ : state) {
    sink.reset();
    gp::sampleAll(sc.shade, *sc.lattice, s, sink, sc.space.get());
    n = sink.samples();
  }
  state.counters["visible_samples"] = static_cast<double>(n);
  state.counters["lattice_samples"] = static_cast<double>(sc.lattice->totalSamples());
  state.counters["empty_bricks"] = sc.space->emptyFraction();
  state.SetItemsProcessed(static_cast<std::int64_t>(n) * state.iterations());
}
BENCHMARK(BM_SampleAll)->ArgName("threads")->Arg(1)->Arg(0)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_SampleLattice(benchmark::State& state) {
  const Scene& sc = scene();
  const pp5::Camera cam = pp5::makeCamera(sc.settings, sc.grid);
  const double step = sc.settings.step(sc.grid);
  for (auto _ : state) {
    const SampleLattice lat(cam, sc.grid, step, sc.settings.maxSamples, static_cast<int>(state.range(0)));
    benchmark::DoNotOptimize(lat.t0s().data());
  }
}
BENCHMARK(BM_SampleLattice)->ArgName("threads")->Arg(1)->Arg(0)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_EmptySpaceMapBuild(benchmark::State& state) {
  const Scene& sc = scene();
  for (auto _ : state) {
    const gp::EmptySpaceMap m(sc.shade, static_cast<int>(state.range(0)));
    benchmark::DoNotOptimize(m.distances());
  }
}
BENCHMARK(BM_EmptySpaceMapBuild)->ArgName("threads")->Arg(1)->Arg(0)->Unit(benchmark::kMillisecond)->UseRealTime();

// The frame at elevation position x: the probe looks down (axial -z), its
// lateral axis along -y, so a sweep moves along x (as sim/probe_motion).
void BM_DBufferAndSampleRegion(benchmark::State& state) {
  const Scene& sc = scene();
  const Grid& g = sc.grid;
  pp5::RenderSettings s = sc.settings;
  s.threads = 1;
  const pp5::Camera cam = sc.lattice->camera();
  const bool bricks = state.range(0) == 1;
  gp::DBuffer db;
  CountingSink sink;
  std::int64_t frame = 0;
  std::uint64_t samples = 0, visible = 0, pixels = 0, boxes = 0;
  constexpr int kPositions = 60;  // x from -59 to +59 mm, 2 mm apart, back and forth
  for (auto _ : state) {
    const std::int64_t p = frame % (2 * (kPositions - 1));
    const double x = -59.0 + 2.0 * static_cast<double>(p < kPositions ? p : 2 * (kPositions - 1) - p);
    std::vector<gp::WorldBox> wb;
    if (bricks) {
      gp::DirtyRegion dirty(g);
      const Vec3 origin(x, 0.5 * kFrameWidthMm, 0.5 * kFrameDepthMm);
      gp::addOrientedSlab(dirty, origin, Vec3(0, -kFrameWidthMm, 0), Vec3(0, 0, -kFrameDepthMm), kTentReachMm);
      wb = gp::stencilBoxes(dirty, 1);
    } else {
      // Voxels whose centres the frame's tents reach.
      const Vec3 lo = g.worldToVoxel(Vec3(x - kTentReachMm.z, -0.5 * kFrameWidthMm - kTentReachMm.x,
                                          -0.5 * kFrameDepthMm - kTentReachMm.y));
      const Vec3 hi = g.worldToVoxel(Vec3(x + kTentReachMm.z, 0.5 * kFrameWidthMm + kTentReachMm.x,
                                          0.5 * kFrameDepthMm + kTentReachMm.y));
      const gp::Box3 box{Index3(glm::ceil(lo)), Index3(glm::floor(hi)) + Index3(1)};
      wb = gp::stencilBoxes(g, std::span<const gp::Box3>(&box, 1), 1);
    }
    db.build(cam, wb);
    sink.reset();
    gp::sampleRegion(sc.shade, *sc.lattice, db, s, sink, sc.space.get());
    samples += sink.samples();
    visible += sink.visible();
    pixels += db.touched().size();
    boxes += wb.size();
    ++frame;
  }
  const double f = static_cast<double>(std::max<std::int64_t>(1, frame));
  state.counters["samples"] = static_cast<double>(samples) / f;
  state.counters["visible"] = static_cast<double>(visible) / f;
  state.counters["pixels"] = static_cast<double>(pixels) / f;
  state.counters["boxes"] = static_cast<double>(boxes) / f;
  state.SetItemsProcessed(static_cast<std::int64_t>(samples));
}
BENCHMARK(BM_DBufferAndSampleRegion)->ArgName("region")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();

// The wire between a GP and a PP: one full view's samples of the scene (one
// thread, in the sampler's order), encoded as the GP sends them (half, the
// default wire) and decoded as the PP takes them in.
class CollectingSink final : public gp::SampleSink {
public:
  void consume(int, std::uint32_t, std::span<const pp5::RaySample> s) override { all.insert(all.end(), s.begin(), s.end()); }
  std::vector<pp5::RaySample> all;
};

const std::vector<pp5::RaySample>& viewSamples() {
  static const std::vector<pp5::RaySample> v = [] {
    const Scene& sc = scene();
    pp5::RenderSettings s = sc.settings;
    s.threads = 1;
    CollectingSink sink;
    gp::sampleAll(sc.shade, *sc.lattice, s, sink, sc.space.get());
    return std::move(sink.all);
  }();
  return v;
}

void BM_EncodeSampleRuns(benchmark::State& state) {
  const auto& samples = viewSamples();
  std::vector<std::byte> wire;
  for (auto _ : state) {
    wire.clear();
    pp5::encodeSampleRuns(samples, pp5::SampleWire::Half, wire);
    benchmark::DoNotOptimize(wire.data());
  }
  state.counters["samples"] = static_cast<double>(samples.size());
  state.counters["wire_MB"] = static_cast<double>(wire.size()) / 1e6;
  state.SetItemsProcessed(static_cast<std::int64_t>(samples.size()) * state.iterations());
}
BENCHMARK(BM_EncodeSampleRuns)->Unit(benchmark::kMillisecond);

void BM_DecodeSampleRuns(benchmark::State& state) {
  const auto& samples = viewSamples();
  std::vector<std::byte> wire;
  pp5::encodeSampleRuns(samples, pp5::SampleWire::Half, wire);
  std::vector<pp5::RaySample> out;
  for (auto _ : state) {
    out.clear();
    if (!pp5::decodeSampleRuns(wire, pp5::SampleWire::Half, out, samples.size())) state.SkipWithError("decode failed");
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(samples.size()) * state.iterations());
}
BENCHMARK(BM_DecodeSampleRuns)->Unit(benchmark::kMillisecond);

}  // namespace
