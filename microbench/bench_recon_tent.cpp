// The 1990 paper's reconstruction on the default doll workload: 256x256
// frames 2 mm apart (about 98 x 195 mm, pixels 0.38 x 0.76 mm) into a 256^3
// grid of 0.8 mm voxels, accumulate, fill-in on. Time per inserted frame,
// fill-in included. Target: <= 10 ms per frame on one core (Release).
//  - TentInsert: the default kernel (2 x 1 x 3 mm half-widths). Frames 2 mm
//    apart are within its 3 mm elevational reach: no fill-in.
//  - TentInsertFillIn: the earlier default, 1 x 0.75 x 1.5 mm, which needs
//    one intermediate slice per gap (fill_in_per_frame = 1).
// Run: build/microbench/pp5_bench --benchmark_filter=TentInsert
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include "core/frame.hpp"
#include "core/grid.hpp"
#include "core/transform.hpp"
#include "reconstruction/splat_tent.hpp"

namespace {

using pp5::Frame;
using pp5::Grid;
using pp5::Mat4;
using pp5::Vec3;

constexpr int kWidth = 256, kHeight = 256;
constexpr double kWidthMm = 98.0, kDepthMm = 195.0, kStepMm = 2.0;
constexpr int kPositions = 100;  // the sweep goes back and forth over +-99 mm

// Fully developed speckle: Rayleigh-distributed amplitudes.
std::vector<Frame> speckleFrames(int count) {
  std::mt19937 rng(1990);
  std::uniform_real_distribution<double> u(1e-12, 1.0);
  std::vector<Frame> frames(static_cast<std::size_t>(count));
  for (Frame& f : frames) {
    f.allocate(kWidth, kHeight, pp5::PixelType::U8);
    for (auto& p : f.pixels) p = static_cast<std::uint8_t>(std::min(255.0, 40.0 * std::sqrt(-2.0 * std::log(u(rng)))));
  }
  return frames;
}

// The simulated probe's orientation (sim/probe_motion.hpp): looking down,
// lateral axis -y, axial axis -z, elevation +x, so a straight sweep moves along
// x. `yawDeg` turns the probe about the vertical axis (the arm's theta);
// `tiltDeg` tips it forward about its lateral axis, as a hand would, so the
// image's axial axis leaves the vertical. The image is centred on the grid.
Mat4 sweepPose(double x, double yawDeg, double tiltDeg) {
  constexpr double kRad = 3.14159265358979323846 / 180.0;
  const Mat4 r = pp5::rotationAxisAngle(Vec3(0, 0, 1), yawDeg * kRad) * pp5::rotationAxisAngle(Vec3(0, 1, 0), tiltDeg * kRad);
  const Vec3 ex = pp5::transformVector(r, Vec3(0, -kWidthMm / (kWidth - 1), 0));
  const Vec3 ey = pp5::transformVector(r, Vec3(0, 0, -kDepthMm / (kHeight - 1)));
  const Vec3 centre(x, 0.0, 0.0);
  Mat4 m(1.0);
  m[0] = pp5::Vec4(ex, 0.0);
  m[1] = pp5::Vec4(ey, 0.0);
  m[2] = pp5::Vec4(glm::normalize(glm::cross(ex, ey)), 0.0);
  m[3] = pp5::Vec4(centre - ex * ((kWidth - 1) * 0.5) - ey * ((kHeight - 1) * 0.5), 1.0);
  return m;
}

// Args: threads (0 = every core), yaw and tilt of the probe in degrees.
void tentInsert(benchmark::State& state, pp5::gp::ReconSettings s) {
  Grid g;
  g.dims = pp5::Index3(256);
  g.spacing = Vec3(0.8);
  g.origin = Vec3(-0.5 * 255 * 0.8);
  s.method = pp5::gp::Method::Tent;
  s.threads = static_cast<int>(state.range(0));
  const double yaw = static_cast<double>(state.range(1)), tilt = static_cast<double>(state.range(2));
  auto rec = pp5::gp::makeTentReconstructor(g, s);
  const std::vector<Frame> frames = speckleFrames(16);

  std::int64_t n = 0, fillIns = 0;
  for (auto _ : state) {
    const std::int64_t p = n % (2 * (kPositions - 1));
    const std::int64_t pos = p < kPositions ? p : 2 * (kPositions - 1) - p;
    const double x = -99.0 + kStepMm * static_cast<double>(pos);
    const auto r = rec->insert(frames[static_cast<std::size_t>(n % 16)], sweepPose(x, yaw, tilt), 0.05 * static_cast<double>(n));
    benchmark::DoNotOptimize(r.pixelsInserted);
    fillIns += r.fillInSlices;
    ++n;
  }
  state.SetItemsProcessed(n);
  state.counters["fill_in_per_frame"] = static_cast<double>(fillIns) / static_cast<double>(std::max<std::int64_t>(1, n));
}

void BM_TentInsert(benchmark::State& state) { tentInsert(state, pp5::gp::ReconSettings{}); }
BENCHMARK(BM_TentInsert)
    ->ArgNames({"threads", "yaw_deg", "tilt_deg"})
    ->Args({1, 0, 0})
    ->Args({1, 30, 0})
    ->Args({1, 0, 15})
    ->Args({0, 0, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

void BM_TentInsertFillIn(benchmark::State& state) {
  pp5::gp::ReconSettings s;
  s.tent.kernelLateralMm = 1.0;
  s.tent.kernelAxialMm = 0.75;
  s.tent.kernelElevationMm = 1.5;
  tentInsert(state, s);
}
BENCHMARK(BM_TentInsertFillIn)
    ->ArgNames({"threads", "yaw_deg", "tilt_deg"})
    ->Args({1, 0, 0})
    ->Args({1, 30, 0})
    ->Args({1, 0, 15})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
