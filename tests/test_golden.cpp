// Golden images: a short doll sweep and a short forearm sweep through the
// serial pipeline, compared with images checked in under tests/golden/. A
// pixel is bad when a channel differs by more than kThreshold grey levels;
// at most kBadFraction of the pixels may be bad, so that a harmless change of
// rounding passes and a real change of the picture does not.
//
// To regenerate after an intended change (and look at the new images before
// committing them): PP5_UPDATE_GOLDEN=1 build/tests/test_golden
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "formats/image_io.hpp"
#include "pipeline/serial_pipeline.hpp"
#include "sim/simulate.hpp"

namespace {

using namespace pp5;

constexpr int kThreshold = 12;
constexpr double kBadFraction = 0.01;

struct GoldenCase {
  std::string name, phantom, probe;
  double lengthMm, intervalMm, spacingMm;
};

std::vector<std::uint8_t> render(const GoldenCase& c, const std::string& mode, int& w, int& h) {
  sim::SimSettings ss;
  ss.phantom = pp5::enumFromName<pp5::sim::PhantomKind>(c.phantom);
  ss.probe.preset = pp5::enumFromName<pp5::sim::ProbePreset>(c.probe);
  ss.probe.widthPx = 128;
  ss.probe.heightPx = 160;
  ss.sweep.captureIntervalMm = c.intervalMm;
  ss.sweep.lengthMm = c.lengthMm;
  ss.threads = 2;
  const sim::SweepSimulator sim(ss);
  std::vector<Mat4> poses;
  for (std::size_t i = 0; i < sim.frameCount(); ++i) poses.push_back(sim.imageToReference(i));
  const Grid g = sim::fitGrid(poses, sim.probe().width, sim.probe().height, Vec3(c.spacingMm), 2.0);
  serial::PipelineSettings ps;
  ps.render.width = w = 160;
  ps.render.height = h = 128;
  ps.render.compositing = {pp5::enumFromName<pp5::CompositeMode>(mode)};
  ps.render.threads = 2;
  if (c.phantom == "forearm") {  // as configs/forearm.toml
    ps.recon.tent.kernelLateralMm = 0.8;
    ps.recon.tent.kernelAxialMm = 0.4;
    ps.recon.tent.kernelElevationMm = 5.0;
    ps.tf.opacity = {{0, 0.0, 0, 0}, {150, 0.0, 0, 0}, {190, 0.25, 0, 0}, {255, 0.8, 0, 0}};
    ps.tf.colour = {{0, 0.0, 0.0, 0.0}, {150, 0.75, 0.6, 0.5}, {220, 1.0, 0.95, 0.85}, {255, 1.0, 1.0, 1.0}};
    ps.render.azimuthDeg = -60.0;
    ps.render.elevationDeg = 50.0;
  }
  serial::SerialPipeline pipe(g, ps);
  sim.run(2, [&](Frame&& f) { pipe.insert(f, poses[f.index], f.timestamp); });
  pipe.finish();
  std::vector<std::uint8_t> rgb(static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * 3);
  const float black[3] = {0, 0, 0};
  pp::toRgb8(pipe.image(), black, rgb.data());
  return rgb;
}

class Golden : public ::testing::TestWithParam<std::tuple<GoldenCase, std::string>> {};

TEST_P(Golden, MatchesTheCheckedInImage) {
  const auto& [c, mode] = GetParam();
  int w = 0, h = 0;
  const std::vector<std::uint8_t> rgb = render(c, mode, w, h);
  const std::string path = std::string(PP5_SOURCE_DIR) + "/tests/golden/" + c.name + "_" + mode + ".png";
  if (std::getenv("PP5_UPDATE_GOLDEN")) {
    writeRgbPng(path, w, h, rgb.data());
    GTEST_SKIP() << "wrote " << path;
  }
  ASSERT_TRUE(std::filesystem::exists(path)) << path << " is missing; see the top of this file";
  const Image8 gold = readImage8(path);
  ASSERT_EQ(gold.width, w);
  ASSERT_EQ(gold.height, h);
  ASSERT_EQ(gold.channels, 3);
  std::size_t bad = 0, lit = 0;
  int worst = 0;
  for (std::size_t p = 0; p < static_cast<std::size_t>(w) * static_cast<std::size_t>(h); ++p) {
    int d = 0;
    for (int ch = 0; ch < 3; ++ch) d = std::max(d, std::abs(rgb[3 * p + ch] - gold.pixels[3 * p + ch]));
    bad += d > kThreshold ? 1 : 0;
    worst = std::max(worst, d);
    lit += gold.pixels[3 * p] + gold.pixels[3 * p + 1] + gold.pixels[3 * p + 2] > 30 ? 1 : 0;
  }
  const double frac = static_cast<double>(bad) / (w * h);
  EXPECT_LE(frac, kBadFraction) << bad << " bad pixels, worst difference " << worst;
  // The golden image shows something (an all-black golden would pass anything black).
  EXPECT_GT(lit, static_cast<std::size_t>(w * h) / 50);
}

INSTANTIATE_TEST_SUITE_P(
    Pipeline, Golden,
    ::testing::Combine(::testing::Values(GoldenCase{"doll", "doll", "paper35", 0.0, 4.0, 2.0},
                                         GoldenCase{"forearm", "forearm", "linear75", 60.0, 2.0, 0.5}),
                       ::testing::Values(std::string("over"), std::string("mip"))),
    [](const auto& i) { return std::get<0>(i.param).name + "_" + std::get<1>(i.param); });

}  // namespace
