// Shading (rendering/shading.hpp) on a 256^3 grid of 0.8 mm voxels holding smooth
// value noise (grey levels 0..255), default transfer function, Phong lit from
// the viewer of the default perspective view: the per-voxel normalisation of
// the direction to the eye makes this the dearest of the lightings.
//  - ShadeFull: every voxel, as after a view or shading change.
//    Target: well under a second on two threads. With sparse:1 the noise
//    below its median is set to 0, so about 60 % of the voxels are
//    transparent, as water and faint speckle around an object make them.
//    counters: visible = share of voxels left with opacity > 0.
//  - ShadeBrick: one 64x64x16 box (65 536 voxels), the size of a frame's
//    dirty region in normal use (50k - 300k voxels).
//  - ShadeDirtySlab: the dirty region of one frame tilted 30 degrees across
//    the grid (16-voxel bricks), grown by the gradient margin; shadingBoxes()
//    included; ShadingBoxes times that decomposition alone.
// Run: build/microbench/pp5_bench --benchmark_filter=Shade
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "core/render_settings.hpp"
#include "core/transfer_function.hpp"
#include "formats/volume_io.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/shade_buffer.hpp"
#include "rendering/shading.hpp"

#include "bench_grid.hpp"

namespace {

using pp5::bench::benchGrid;

using pp5::Grid;
using pp5::Index3;
using pp5::Vec3;

// Two octaves of value noise: random lattices every 16 and 4 voxels,
// interpolated trilinearly, weighted 0.8 and 0.2.
pp5::Volume makeNoiseVolume() {
  const Grid g = benchGrid();
  pp5::Volume vol;
  vol.allocate(g, pp5::ScalarType::F32);
  std::mt19937 rng(1988);
  std::uniform_real_distribution<float> u(0.0f, 255.0f);
  struct Octave {
    int period;
    float weight;
    std::int64_t n;
    std::vector<float> lattice;
  };
  std::vector<Octave> octaves = {{16, 0.8f, 0, {}}, {4, 0.2f, 0, {}}};
  for (auto& o : octaves) {
    o.n = g.dims.x / o.period + 2;
    o.lattice.resize(static_cast<std::size_t>(o.n * o.n * o.n));
    for (auto& x : o.lattice) x = u(rng);
  }
  std::vector<float> row(static_cast<std::size_t>(g.dims.x));
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j) {
      std::fill(row.begin(), row.end(), 0.0f);
      for (const auto& o : octaves) {
        const float fy = float(j % o.period) / o.period, fz = float(k % o.period) / o.period;
        const std::int64_t ly = j / o.period, lz = k / o.period;
        auto L = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
          return o.lattice[static_cast<std::size_t>((z * o.n + y) * o.n + x)];
        };
        for (std::int64_t i = 0; i < g.dims.x; ++i) {
          const float fx = float(i % o.period) / o.period;
          const std::int64_t lx = i / o.period;
          float c[2];
          for (int dz = 0; dz < 2; ++dz) {
            const float a = L(lx, ly, lz + dz) + fx * (L(lx + 1, ly, lz + dz) - L(lx, ly, lz + dz));
            const float b = L(lx, ly + 1, lz + dz) + fx * (L(lx + 1, ly + 1, lz + dz) - L(lx, ly + 1, lz + dz));
            c[dz] = a + fy * (b - a);
          }
          row[static_cast<std::size_t>(i)] += o.weight * (c[0] + fz * (c[1] - c[0]));
        }
      }
      for (std::int64_t i = 0; i < g.dims.x; ++i) vol.setValue(g.linear(i, j, k), row[static_cast<std::size_t>(i)]);
    }
  return vol;
}

const pp5::Volume& noiseVolume(bool sparse) {
  static const pp5::Volume dense = makeNoiseVolume();
  static const pp5::Volume water = [] {
    pp5::Volume v = dense;
    for (std::size_t n = 0; n < v.grid.voxelCount(); ++n) v.setValue(n, std::max(0.0, 2.0 * (v.value(n) - 128.0)));
    return v;
  }();
  return sparse ? water : dense;
}

double visibleShare(const pp5::gp::ShadeBuffer& b) {
  std::uint64_t n = 0;
  for (std::uint64_t i = 0; i < b.grid().voxelCount(); ++i) n += b.at(i).a > 0;
  return static_cast<double>(n) / static_cast<double>(b.grid().voxelCount());
}

struct Fixture {
  const pp5::Volume& vol;
  pp5::TransferFunction tf;
  pp5::gp::ShadeSettings s;
  pp5::Camera cam = pp5::makeCamera(pp5::RenderSettings{}, benchGrid());
  pp5::gp::ShadeBuffer out{benchGrid()};
  explicit Fixture(const benchmark::State& state, bool sparse = false) : vol(noiseVolume(sparse)) {
    s.threads = static_cast<int>(state.range(0));
  }
};

void BM_ShadeFull(benchmark::State& state) {
  Fixture f(state, state.range(1) != 0);
  const pp5::gp::Box3 all{Index3(0), f.vol.grid.dims};
  for (auto _ : state) {
    pp5::gp::shade(f.vol, f.tf, f.s, f.cam, all, f.out);
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(all.voxelCount()));
  state.counters["visible"] = visibleShare(f.out);
}
BENCHMARK(BM_ShadeFull)
    ->ArgNames({"threads", "sparse"})
    ->ArgsProduct({{1, 0}, {0, 1}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

void BM_ShadeBrick(benchmark::State& state) {
  Fixture f(state);
  const pp5::gp::Box3 box{{96, 96, 120}, {160, 160, 136}};
  for (auto _ : state) {
    pp5::gp::shade(f.vol, f.tf, f.s, f.cam, box, f.out);
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(box.voxelCount()));
}
BENCHMARK(BM_ShadeBrick)->ArgName("threads")->Arg(1)->Arg(0)->Unit(benchmark::kMillisecond)->UseRealTime();

// A 98 x 195 mm image through the grid's centre, turned 30 degrees about z,
// reaching the default tent kernel's half-widths (2, 1, 3 mm).
pp5::gp::DirtyRegion slabRegion() {
  pp5::gp::DirtyRegion dirty(benchGrid());
  const double a = 30.0 * 3.14159265358979323846 / 180.0;
  const Vec3 u(-98.0 * std::sin(a), 98.0 * std::cos(a), 0.0), v(0.0, 0.0, -195.0);
  pp5::gp::addOrientedSlab(dirty, -0.5 * u - 0.5 * v, u, v, Vec3(2.0, 1.0, 3.0));
  return dirty;
}

void BM_ShadeDirtySlab(benchmark::State& state) {
  Fixture f(state);
  const pp5::gp::DirtyRegion dirty = slabRegion();
  std::uint64_t voxels = 0;
  for (const auto& b : pp5::gp::shadingBoxes(dirty)) voxels += b.voxelCount();
  for (auto _ : state) {
    pp5::gp::shade(f.vol, f.tf, f.s, f.cam, dirty, f.out);
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(voxels));
  state.counters["voxels"] = static_cast<double>(voxels);
}
BENCHMARK(BM_ShadeDirtySlab)->ArgName("threads")->Arg(1)->Arg(0)->Unit(benchmark::kMillisecond)->UseRealTime();

// The region's decomposition alone (part of ShadeDirtySlab's time).
void BM_ShadingBoxes(benchmark::State& state) {
  const pp5::gp::DirtyRegion dirty = slabRegion();
  std::size_t boxes = 0;
  for (auto _ : state) boxes = pp5::gp::shadingBoxes(dirty).size();
  state.counters["bricks"] = static_cast<double>(dirty.bricks().size());
  state.counters["boxes"] = static_cast<double>(boxes);
}
BENCHMARK(BM_ShadingBoxes)->Unit(benchmark::kMicrosecond);

}  // namespace
