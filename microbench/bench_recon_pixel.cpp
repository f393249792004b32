// PLUS-compatible pixel reconstruction on PLUS's own test recording:
// SpinePhantomFreehand (21 frames of 820x616 pixels, 8 bit) with the
// ImageToProbe calibration of the NN_MEAN config, into PLUS's automatic
// 0.5 mm grid (147 x 106 x 105 voxels). MEAN compounding, no hole filling,
// one thread. Time per inserted frame, output update included.
// Targets (one core, Release): nearest <= 2 ms, trilinear <= 10 ms per frame
// (PLUS: 4.1 ms and 44 ms on this machine class).
// Run: build/microbench/pp5_bench --benchmark_filter=PixelInsert
#include <benchmark/benchmark.h>

#include <memory>
#include <string>
#include <vector>

#include "core/frame.hpp"
#include "core/grid.hpp"
#include "formats/plus_config.hpp"
#include "formats/sequence_io.hpp"
#include "reconstruction/reconstruction.hpp"

namespace {

using namespace pp5;

struct Recording {
  std::vector<Frame> frames;
  std::vector<Mat4> poses;
  PlusConfig cfg;
};

Recording load(const std::string& sequence, const std::string& config) {
  const std::string dir = PP5_DATA_DIR;
  Recording rec;
  rec.cfg = readPlusConfig(dir + "/" + config);
  for (Frame& f : readAllFrames(dir + "/" + sequence))
    if (auto m = imageToReference(rec.cfg, f)) {
      rec.frames.push_back(std::move(f));
      rec.poses.push_back(*m);
    }
  return rec;
}

const Recording& recording() {
  static const Recording r =
      load("SpinePhantomFreehand.igs.mha", "PlusDeviceSet_VolumeReconstructionOnly_SpinePhantom_NN_MEAN.xml");
  return r;
}

// fCal 2.0's calibration recording (190 frames of 820x616 pixels of 0.08 x
// 0.074 mm, a calibration whose pixel grid is sheared by 0.27 mm over the
// image's depth) with its volume reconstruction config.
const Recording& fcal() {
  static const Recording r =
      load("fCal_Test_Calibration_3NWires_fCal2.0.igs.mha", "PlusDeviceSet_fCal_Sim_VolumeReconstruction.xml");
  return r;
}

// Every frame of `rec` in turn into its PLUS grid of 0.5 mm, a fresh volume
// for every pass over the recording, one thread: time per inserted frame.
void insertFrames(benchmark::State& state, const Recording& rec, const gp::ReconSettings& s) {
  if (rec.frames.empty()) {
    state.SkipWithError("no frames with a valid pose");
    return;
  }
  const Grid g = gp::plusOutputGrid(rec.poses, rec.frames[0].width, rec.frames[0].height, s, Vec3(0.5));
  std::unique_ptr<gp::Reconstructor> r;
  std::size_t k = 0;
  std::uint64_t pixels = 0;
  for (auto _ : state) {
    // A fresh volume for every pass, so that the hit counts per voxel stay
    // those of the real sweep.
    if (k % rec.frames.size() == 0) {
      state.PauseTiming();
      r = gp::makeReconstructor(g, s);
      state.ResumeTiming();
    }
    const std::size_t f = k++ % rec.frames.size();
    pixels += r->insert(rec.frames[f], rec.poses[f], rec.frames[f].timestamp).pixelsInserted;
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(pixels));
}

// Args: method (0 nearest, 1 trilinear), arithmetic (0 float, 1 plus).
void BM_PixelInsert(benchmark::State& state) {
  const Recording& rec = recording();
  gp::ReconSettings s = gp::fromPlus(*rec.cfg.volumeReconstruction);
  s.method = state.range(0) == 0 ? gp::Method::Nearest : gp::Method::Trilinear;
  s.arithmetic = state.range(1) == 0 ? gp::Arithmetic::Float : gp::Arithmetic::Plus;
  s.pixel.compounding = pp5::gp::Compounding::Mean;
  s.pixel.fillHoles = false;
  s.threads = 1;
  insertFrames(state, rec, s);
  state.SetLabel(std::string(pp5::enumName(s.method)) + " " + std::string(pp5::enumName(s.arithmetic)));
}
BENCHMARK(BM_PixelInsert)
    ->ArgNames({"trilinear", "plus"})
    ->Args({0, 0})
    ->Args({0, 1})
    ->Args({1, 0})
    ->Args({1, 1})
    ->Unit(benchmark::kMillisecond);

// The fCal 2.0 recording into its 0.5 mm grid (112x152x83 voxels, as PLUS
// sizes it), one core, its config's settings: the tent at its default half-widths
// (BM_TentInsert/recording:fcal2) and trilinear splatting
// (BM_PixelInsert/recording:fcal2), the comparison of issue 39.
void onFcal(benchmark::State& state, gp::Method method) {
  gp::ReconSettings s = gp::fromPlus(*fcal().cfg.volumeReconstruction);
  s.method = method;
  s.arithmetic = gp::Arithmetic::Float;
  s.threads = 1;
  insertFrames(state, fcal(), s);
}
const auto* const kTentFcal =
    benchmark::RegisterBenchmark("BM_TentInsert/recording:fcal2", onFcal, gp::Method::Tent)->Unit(benchmark::kMillisecond);
const auto* const kTrilinearFcal = benchmark::RegisterBenchmark("BM_PixelInsert/recording:fcal2", onFcal,
                                                                gp::Method::Trilinear)->Unit(benchmark::kMillisecond);

}  // namespace
