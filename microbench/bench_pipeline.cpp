// The serial pipeline on issue 4's workload: the simulated doll swept with
// 256x256 frames 2 mm apart into a 256^3 grid of 0.8 mm, shown at 512x512
// with up to 512 samples per ray, the default transfer function, Phong
// shading, "over" compositing.
//  - BM_PipelineIncremental: shade + sample + composite after one frame, one
//    thread (target 33 ms: the paper's 30 Hz). Reconstruction runs but is not
//    counted (its own benchmark is BM_TentInsert).
//  - BM_PipelineViewChange: a full re-render after the view turns by 10
//    degrees (lattice, re-shade, re-sample, composite), both cores (target 150 ms).
// Run: build/microbench/pp5_bench --benchmark_filter=Pipeline --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>
#include <sys/resource.h>

#include <memory>
#include <vector>

#include "pipeline/serial_pipeline.hpp"
#include "sim/simulate.hpp"

namespace {

using namespace pp5;

struct Workload {
  std::vector<Frame> frames;
  std::vector<Mat4> poses;
  Grid grid;
};

const Workload& workload() {
  static const Workload w = [] {
    sim::SimSettings ss;
    ss.phantom = pp5::sim::PhantomKind::Doll;
    ss.probe.widthPx = 256;
    ss.probe.heightPx = 256;
    ss.sweep.captureIntervalMm = 2.0;
    ss.threads = 0;
    const sim::SweepSimulator sim(ss);
    Workload out;
    sim.run(0, [&](Frame&& f) {
      out.poses.push_back(sim.imageToReference(f.index));
      out.frames.push_back(std::move(f));
    });
    // 256^3 voxels of 0.8 mm around the sweep's centre.
    const Grid fit = sim::fitGrid(out.poses, sim.probe().width, sim.probe().height, Vec3(0.8), 0.0);
    const Vec3 centre = fit.voxelToWorld(0.5 * Vec3(fit.dims - Index3(1)));
    out.grid.spacing = Vec3(0.8);
    out.grid.dims = Index3(256);
    out.grid.origin = centre - 0.5 * 255.0 * out.grid.spacing;
    return out;
  }();
  return w;
}

serial::PipelineSettings settings(int threads) {
  serial::PipelineSettings ps;
  ps.render.width = 512;
  ps.render.height = 512;
  ps.render.maxSamples = 512;
  ps.render.stepMm = 0.8;  // 512 samples span the 355 mm diagonal of the grid
  ps.render.compositing = {pp5::CompositeMode::Over};
  ps.render.threads = threads;
  ps.recon.threads = threads;
  return ps;
}

void BM_PipelineIncremental(benchmark::State& state) {
  const Workload& w = workload();
  serial::SerialPipeline pipe(w.grid, settings(1));
  std::size_t i = 0;
  // The first third of the sweep, so that later frames land next to data.
  for (; i < w.frames.size() / 3; ++i) pipe.insert(w.frames[i], w.poses[i], w.frames[i].timestamp);
  std::uint64_t samples = 0, n = 0, dirty = 0, shaded = 0, pixels = 0, rays = 0, blocks = 0, faults = 0;
  auto minorFaults = [] {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return static_cast<std::uint64_t>(u.ru_minflt);
  };
  double shadeMs = 0.0, sampleMs = 0.0, compositeMs = 0.0;
  for (auto _ : state) {
    if (i == w.frames.size()) {
      state.SkipWithError("ran out of frames; lower the iterations");
      break;
    }
    const std::uint64_t faultsBefore = minorFaults();
    const serial::FrameStats st = pipe.insert(w.frames[i], w.poses[i], w.frames[i].timestamp);
    faults += minorFaults() - faultsBefore;
    ++i;
    state.SetIterationTime((st.shadeMs + st.sampleMs + st.compositeMs) / 1000.0);
    samples += st.samples;
    dirty += st.dirtyVoxels;
    shaded += st.shadedVoxels;
    pixels += st.dbufferPixels;
    rays += st.raysComposited;
    blocks += st.blocksComposited;
    shadeMs += st.shadeMs;
    sampleMs += st.sampleMs;
    compositeMs += st.compositeMs;
    ++n;
  }
  const double frames = static_cast<double>(std::max<std::uint64_t>(1, n));
  state.counters["samples_per_frame"] = static_cast<double>(samples) / frames;
  // The work's size: voxels the frame dirtied, voxels shaded (the dirty bricks
  // and their gradient margin), and pixels the D-buffer found.
  state.counters["dirty_voxels"] = static_cast<double>(dirty) / frames;
  state.counters["shaded_voxels"] = static_cast<double>(shaded) / frames;
  state.counters["dbuffer_pixels"] = static_cast<double>(pixels) / frames;
  // Compositing's work: rays walked, block partials recomputed.
  state.counters["rays_composited"] = static_cast<double>(rays) / frames;
  state.counters["blocks_composited"] = static_cast<double>(blocks) / frames;
  // Fresh pages of memory the frame wrote (minor page faults, every stage
  // including reconstruction): the kernel zeroes each, at a cost the timed
  // stages pay when they are the cache's.
  state.counters["page_faults"] = static_cast<double>(faults) / frames;
  // Where the time goes: shading (and the empty-space map), D-buffer and
  // sampling, putting and compositing; ms per frame.
  state.counters["shade_ms"] = shadeMs / frames;
  state.counters["sample_ms"] = sampleMs / frames;
  state.counters["composite_ms"] = compositeMs / frames;
}
BENCHMARK(BM_PipelineIncremental)->UseManualTime()->Unit(benchmark::kMillisecond)->Iterations(20);

void BM_PipelineViewChange(benchmark::State& state) {
  const Workload& w = workload();
  serial::SerialPipeline pipe(w.grid, settings(0));
  for (std::size_t i = 0; i < w.frames.size(); ++i) pipe.insert(w.frames[i], w.poses[i], w.frames[i].timestamp);
  const Camera base = pipe.camera();
  int turn = 0;
  for (auto _ : state) pipe.setCamera(base.orbited(Vec3(0, 0, 1), 10.0 * (++turn)));
  state.counters["cache_MiB"] = static_cast<double>(pipe.cache().memoryBytes()) / (1 << 20);
}
BENCHMARK(BM_PipelineViewChange)->Unit(benchmark::kMillisecond)->Iterations(8)->UseRealTime();

}  // namespace
