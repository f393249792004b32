// The serial pipeline end to end: after every frame, the incrementally kept
// image equals a from-scratch render of the current grid, bitwise, for every
// composition mode, both shading modes and both projections.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "host/serial_pipeline.hpp"
#include "sim/simulate.hpp"

namespace {

using namespace pp5;

struct Case {
  std::string mode, shading, projection;
};

void PrintTo(const Case& c, std::ostream* os) { *os << c.mode << "/" << c.shading << "/" << c.projection; }

std::string name(const ::testing::TestParamInfo<Case>& i) {
  return i.param.mode + "_" + i.param.shading + "_" + i.param.projection;
}

class IncrementalEqualsFull : public ::testing::TestWithParam<Case> {};

// A short doll sweep with small frames, into a 2 mm grid, shown at 96x80.
TEST_P(IncrementalEqualsFull, AfterEveryFrame) {
  const Case c = GetParam();
  sim::SimSettings ss;
  ss.phantom = "doll";
  ss.probe.widthPx = 64;
  ss.probe.heightPx = 100;
  ss.sweep.captureIntervalMm = 4.0;
  ss.sweep.lengthMm = 60.0;
  ss.threads = 2;
  const sim::SweepSimulator sim(ss);
  ASSERT_GE(sim.frameCount(), 8u);
  std::vector<Mat4> poses;
  for (std::size_t i = 0; i < sim.frameCount(); ++i) poses.push_back(sim.imageToReference(i));
  const Grid g = sim::fitGrid(poses, sim.probe().width, sim.probe().height, Vec3(2.0), 2.0);

  host::PipelineSettings ps;
  ps.render.width = 96;
  ps.render.height = 80;
  ps.render.projection = c.projection;
  ps.render.compositing = {c.mode};
  ps.render.threads = 2;
  ps.shading.mode = c.shading;
  host::SerialPipeline pipe(g, ps);
  const pp::CompositeMode mode = pp::compositeModeFromName(c.mode);

  std::size_t nonBlank = 0;
  for (std::size_t i = 0; i < sim.frameCount(); ++i) {
    const Frame f = sim.frame(i);
    pipe.insert(f, poses[i], f.timestamp);
    const pp::TileImage full = pipe.renderFromScratch(mode);
    const pp::TileImage& inc = pipe.image();
    ASSERT_EQ(inc.rgba.size(), full.rgba.size());
    std::size_t differ = 0;
    float worst = 0.0f;
    for (std::size_t k = 0; k < inc.rgba.size(); ++k)
      if (inc.rgba[k] != full.rgba[k]) {
        ++differ;
        worst = std::max(worst, std::abs(inc.rgba[k] - full.rgba[k]));
      }
    ASSERT_EQ(differ, 0u) << "frame " << i << ": " << differ << " channels differ, by up to " << worst;
    nonBlank = 0;
    for (std::size_t k = 0; k + 3 < inc.rgba.size(); k += 4)
      nonBlank += inc.rgba[k] + inc.rgba[k + 1] + inc.rgba[k + 2] > 0.0f ? 1 : 0;
  }
  // Something was drawn: the doll's shell is in view.
  EXPECT_GT(nonBlank, 200u);
}

INSTANTIATE_TEST_SUITE_P(Pipeline, IncrementalEqualsFull,
                         ::testing::Values(Case{"over", "phong", "perspective"}, Case{"over", "value", "perspective"},
                                           Case{"over", "phong", "orthographic"}, Case{"mip", "phong", "perspective"},
                                           Case{"mip", "value", "orthographic"},
                                           Case{"additive", "phong", "perspective"},
                                           Case{"additive", "value", "orthographic"}),
                         name);

}  // namespace
