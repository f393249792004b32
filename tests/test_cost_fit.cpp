// The predictive cost model's parts (harness/cost_fit, serial/work_census):
// the census counts what the serial pipeline did, rankWork splits it as the
// layouts' real slab cuts and tile owners do, and the fit recovers known
// per-unit costs.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <numeric>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/error.hpp"
#include "benchmark/cost_fit.hpp"
#include "pipeline/schedule.hpp"
#include "pipeline/serial_pipeline.hpp"
#include "pipeline/work_census.hpp"
#include "sim/simulate.hpp"
#include "sweep_test_util.hpp"

namespace {

using namespace pp5;
using namespace pp5::harness;

double sum(const std::vector<double>& v) { return std::accumulate(v.begin(), v.end(), 0.0); }

// A small doll sweep through the serial pipeline with a census.
TEST(WorkCensus, CountsWhatTheSerialPipelineDid) {
  const sim::SweepSimulator sim(test::smallDollSweep());
  const auto [poses, g] = test::sweepGrid(sim);
  serial::PipelineSettings ps;
  ps.render.width = 96;
  ps.render.height = 64;
  ps.render.threads = 2;
  serial::SerialPipeline pipe(g, ps);
  serial::WorkCensus census(g, 96, 64, 32);
  pipe.setCensus(&census);
  double dirty = 0, shaded = 0, samples = 0;
  for (std::size_t i = 0; i < sim.frameCount(); ++i) {
    const Frame f = sim.frame(i);
    const serial::FrameStats st = pipe.insert(f, poses[i], f.timestamp);
    dirty += static_cast<double>(st.dirtyVoxels);
    shaded += static_cast<double>(st.shadedVoxels);
    samples += static_cast<double>(st.samples);
  }
  ASSERT_GT(samples, 0.0);
  const std::string path = (std::filesystem::temp_directory_path() / "pp5_test_census.json").string();
  census.write(path);
  const Census c = readCensus(path);
  // A census whose bins do not agree with its image, or with a footprint out of its bins, is refused.
  {
    std::ifstream in(path);
    const nlohmann::json good = nlohmann::json::parse(in);
    auto refused = [&](const char* what, const std::function<void(nlohmann::json&)>& spoil) {
      nlohmann::json bad = good;
      spoil(bad);
      std::ofstream(path) << bad.dump();
      EXPECT_THROW(readCensus(path), InputError) << what;
    };
    refused("bin_px 0", [](nlohmann::json& j) { j["bin_px"] = 0; });
    refused("bins", [](nlohmann::json& j) { j["bins"][0] = 7; });
    refused("footprint", [](nlohmann::json& j) { j["dirty_voxels_by_footprint"].push_back({0, 0, 9, 0, 1.0}); });
    refused("schema", [](nlohmann::json& j) { j["schema"] = "other"; });
  }
  std::filesystem::remove(path);
  EXPECT_EQ(c.frames, static_cast<double>(sim.frameCount()));
  EXPECT_EQ(c.binsX, 3);
  EXPECT_EQ(c.binsY, 2);
  for (int a = 0; a < 3; ++a) {
    const auto ua = static_cast<std::size_t>(a);
    EXPECT_DOUBLE_EQ(sum(c.recon[ua]), dirty) << "axis " << a;
    EXPECT_DOUBLE_EQ(sum(c.shaded[ua]), shaded) << "axis " << a;
    EXPECT_DOUBLE_EQ(sum(c.samples[ua]), samples) << "axis " << a;
  }
  // Every screen bin has the same samples whichever axis its layers run along.
  for (int b = 0; b < c.binsX * c.binsY; ++b) {
    std::array<double, 3> perAxis{};
    for (std::size_t a = 0; a < 3; ++a) {
      const auto cells = static_cast<std::size_t>(c.dims[a] - 1);
      for (std::size_t l = 0; l < cells; ++l) perAxis[a] += c.samples[a][static_cast<std::size_t>(b) * cells + l];
    }
    EXPECT_DOUBLE_EQ(perAxis[0], perAxis[1]);
    EXPECT_DOUBLE_EQ(perAxis[0], perAxis[2]);
  }
  double footprints = 0;
  for (const Census::Footprint& f : c.footprints) {
    EXPECT_LE(f.x0, f.x1);
    EXPECT_LE(f.y0, f.y1);
    EXPECT_LT(f.x1, c.binsX);
    EXPECT_LT(f.y1, c.binsY);
    footprints += f.voxels;
  }
  EXPECT_GT(footprints, 0.0);
  EXPECT_LE(footprints, dirty);  // bricks off screen are left out
}

// A census with known numbers: a 33x17x17 grid (32 cells along x, the slab
// axis), a 64x64 image in 32-pixel bins, 4 frames.
Census syntheticCensus() {
  Census c;
  c.dims = {33, 17, 17};
  c.width = c.height = 64;
  c.binPx = 32;
  c.binsX = c.binsY = 2;
  c.frames = 4;
  c.framePixelBytes = 1000;
  for (std::size_t a = 0; a < 3; ++a) {
    c.recon[a].assign(static_cast<std::size_t>(c.dims[a]), 0.0);
    c.shaded[a].assign(static_cast<std::size_t>(c.dims[a]), 0.0);
    c.samples[a].assign(static_cast<std::size_t>(4 * (c.dims[a] - 1)), 0.0);
  }
  for (std::size_t i = 0; i < 33; ++i) c.recon[0][i] = static_cast<double>(i + 1);
  for (std::size_t b = 0; b < 4; ++b)
    for (std::size_t l = 0; l < 32; ++l) c.samples[0][b * 32 + l] = static_cast<double>((b + 1) * 100 + l);
  // Frames dirty in x [0, 4), [10, 14), [20, 24), [30, 33).
  c.frameRanges = {{0, 4, 0, 17, 0, 17}, {10, 14, 0, 17, 0, 17}, {20, 24, 0, 17, 0, 17}, {30, 33, 0, 17, 0, 17}};
  c.footprints = {{0, 0, 0, 0, 7.0}, {1, 1, 1, 1, 11.0}, {0, 0, 1, 0, 13.0}};
  return c;
}

double samplesIn(const Census& c, int bin, int lo, int hi) {
  double s = 0;
  for (int l = lo; l < hi; ++l) s += c.samples[0][static_cast<std::size_t>(bin * 32 + l)];
  return s;
}

TEST(CostModel, SlabRanksGetTheirLayers) {
  const Census c = syntheticCensus();
  const std::vector<RankWork> w = rankWork(c, makeLayout(2, 1, "slab"));
  ASSERT_EQ(w.size(), 4u);
  EXPECT_EQ(w[0].role, RankRole::Host);
  EXPECT_EQ(w[1].role, RankRole::Gp);
  EXPECT_EQ(w[3].role, RankRole::Pp);
  // Cells [0, 16) and [16, 32): windows of voxels [0, 18) and [15, 33) with the ghost layer.
  auto layers = [&](int lo, int hi) { return std::accumulate(c.recon[0].begin() + lo, c.recon[0].begin() + hi, 0.0); };
  EXPECT_DOUBLE_EQ(w[1].reconVoxels, layers(0, 18));
  EXPECT_DOUBLE_EQ(w[2].reconVoxels, layers(15, 33));
  EXPECT_DOUBLE_EQ(w[1].scanVoxels, layers(0, 17));
  double s0 = 0, s1 = 0;
  for (int b = 0; b < 4; ++b) {
    s0 += samplesIn(c, b, 0, 16);
    s1 += samplesIn(c, b, 16, 32);
  }
  EXPECT_DOUBLE_EQ(w[1].samples, s0);
  EXPECT_DOUBLE_EQ(w[2].samples, s1);
  EXPECT_DOUBLE_EQ(w[3].samples, s0 + s1);  // the one PP receives every sample
  EXPECT_DOUBLE_EQ(w[3].ownedTiles, 1.0);
  // Frames 0 and 1 reach GP 0's window [0, 18), frames 2 and 3 GP 1's [15, 33).
  EXPECT_DOUBLE_EQ(w[1].pixelFrames, 2);
  EXPECT_DOUBLE_EQ(w[2].pixelFrames, 2);
  EXPECT_DOUBLE_EQ(w[0].pixelBytes, 4 * 1000.0);
  EXPECT_DOUBLE_EQ(w[1].frames, 4);
}

TEST(CostModel, TileRanksGetTheirTiles) {
  const Census c = syntheticCensus();
  // 32-pixel tiles, 4 of them; contiguous owners: GP 0 tiles 0, 1 (the top
  // row of bins), GP 1 tiles 2, 3. Interleaved PPs: PP 0 tiles 0, 2.
  Layout l = makeLayout(2, 2, "tile", "contiguous", 32);
  std::vector<RankWork> w = rankWork(c, l);
  ASSERT_EQ(w.size(), 5u);
  const double all = sum(c.recon[0]);
  EXPECT_DOUBLE_EQ(w[1].reconVoxels, all);
  EXPECT_DOUBLE_EQ(w[2].reconVoxels, all);
  EXPECT_DOUBLE_EQ(w[1].samples, samplesIn(c, 0, 0, 32) + samplesIn(c, 1, 0, 32));
  EXPECT_DOUBLE_EQ(w[2].samples, samplesIn(c, 2, 0, 32) + samplesIn(c, 3, 0, 32));
  // Footprints: bin (0,0) -> GP 0; bin (1,1) -> GP 1; bins (0,0)-(1,0) -> GP 0.
  EXPECT_DOUBLE_EQ(w[1].scanVoxels, 7.0 + 13.0);
  EXPECT_DOUBLE_EQ(w[2].scanVoxels, 11.0);
  EXPECT_DOUBLE_EQ(w[0].pixelBytes, 2 * 4 * 1000.0);  // every GP gets every frame's pixels
  l.owner = "interleaved";
  w = rankWork(c, l);
  EXPECT_DOUBLE_EQ(w[3].samples, samplesIn(c, 0, 0, 32) + samplesIn(c, 2, 0, 32));
  EXPECT_DOUBLE_EQ(w[4].samples, samplesIn(c, 1, 0, 32) + samplesIn(c, 3, 0, 32));
  EXPECT_DOUBLE_EQ(w[3].ownedTiles, 0.5);
  // A tile size the bins cannot make is refused.
  EXPECT_THROW(rankWork(c, makeLayout(2, 1, "tile", "contiguous", 48)), InputError);
}

// Observations made from known unit costs: the fit gets them back, and the
// prediction of a layout it did not see follows the machine rule.
TEST(CostModel, FitRecoversKnownCostsAndPredicts) {
  const Census c = syntheticCensus();
  UnitCosts truth;
  truth.gp = {2e-3, 3e-3, 1e-3, 5e-5, 0.0};
  truth.pp = {2e-5, 0.05, 0.01, 0.0};
  truth.host = {4e-3, 1e-6, 0.0};
  auto cpuOf = [&](const RankWork& w, double streamS) {
    switch (w.role) {
      case RankRole::Gp:
        return truth.gp[0] * w.frames + truth.gp[1] * w.reconVoxels + truth.gp[2] * w.scanVoxels +
               truth.gp[3] * w.samples;
      case RankRole::Pp: return truth.pp[0] * w.samples + truth.pp[1] * streamS * w.ownedTiles + truth.pp[2] * streamS;
      case RankRole::Host: break;
    }
    return truth.host[0] * w.frames + truth.host[1] * w.pixelBytes;
  };
  std::vector<Observation> obs;
  const std::vector<Layout> fit = {makeLayout(1, 1, "slab", "contiguous", 32), makeLayout(2, 1, "slab", "contiguous", 32),
                                   makeLayout(2, 2, "tile", "contiguous", 32), makeLayout(3, 1, "tile", "interleaved", 32),
                                   makeLayout(1, 2, "tile", "contiguous", 64), makeLayout(3, 3, "slab", "interleaved", 32)};
  double stream = 1.0;
  for (const Layout& l : fit) {
    Observation o;
    o.layout = l;
    o.streamS = stream;
    stream += 0.7;
    for (const RankWork& w : rankWork(c, l)) {
      o.cpuS.push_back(cpuOf(w, o.streamS));
      o.bytesMoved.push_back(0.0);
    }
    obs.push_back(o);
  }
  const UnitCosts u = fitCosts(c, obs);
  auto near = [](double a, double b) { return std::abs(a - b) <= 1e-6 * std::max(1.0, std::abs(b)) + 1e-12; };
  for (std::size_t i = 0; i < 4; ++i) EXPECT_PRED2(near, u.gp[i], truth.gp[i]) << "GP cost " << i;
  for (std::size_t i = 0; i < 3; ++i) EXPECT_PRED2(near, u.pp[i], truth.pp[i]) << "PP cost " << i;
  for (std::size_t i = 0; i < 2; ++i) EXPECT_PRED2(near, u.host[i], truth.host[i]) << "host cost " << i;

  // An unseen layout on 2 cores: the stream lasts max(sum / 2, busiest).
  const Layout unseen = makeLayout(4, 1, "slab", "contiguous", 32);
  const Prediction p = predict(c, unseen, u, 2);
  const std::vector<RankWork> w = rankWork(c, unseen);
  ASSERT_EQ(p.rankCpuS.size(), w.size());
  double total = 0, busiest = 0;
  for (std::size_t r = 0; r < w.size(); ++r) {
    const double steady = cpuOf(w[r], p.streamS);
    EXPECT_NEAR(p.rankCpuS[r], steady, 1e-9) << "rank " << r;
    total += steady;
    busiest = std::max(busiest, steady);
  }
  EXPECT_NEAR(p.streamS, std::max(total / 2, busiest), 1e-6);
  EXPECT_NEAR(p.framesPerS, c.frames / p.streamS, 1e-9);
}

// A cost the data would make negative is held at zero, and the rest refitted.
TEST(CostModel, CostsStayNonNegative) {
  const Census c = syntheticCensus();
  std::vector<Observation> obs;
  for (int g = 1; g <= 4; ++g)
    for (const char* part : {"slab", "tile"}) {
      Observation o;
      o.layout = makeLayout(g, 1, part, "contiguous", 32);
      o.streamS = 1.0;
      for (const RankWork& w : rankWork(c, o.layout)) {
        // GP CPU falls with its samples: the samples' cost must not go negative.
        o.cpuS.push_back(w.role == RankRole::Gp ? 0.01 * w.frames + 1e-3 * w.reconVoxels - 1e-4 * w.samples : 0.1);
        o.bytesMoved.push_back(0.0);
      }
      obs.push_back(o);
    }
  const UnitCosts u = fitCosts(c, obs);
  for (double k : u.gp) EXPECT_GE(k, 0.0);
  EXPECT_EQ(u.gp[3], 0.0);
}

}  // namespace
