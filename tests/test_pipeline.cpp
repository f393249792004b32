// The serial pipeline end to end: after every frame, the incrementally kept
// image equals a from-scratch render of the current grid, bitwise, for every
// composition mode, both shading modes and both projections.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "pipeline/serial_pipeline.hpp"
#include "sim/simulate.hpp"
#include "sweep_test_util.hpp"

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
  const sim::SweepSimulator sim(test::smallDollSweep());
  ASSERT_GE(sim.frameCount(), 8u);
  const auto [poses, g] = test::sweepGrid(sim);

  serial::PipelineSettings ps;
  ps.render.width = 96;
  ps.render.height = 80;
  ps.render.projection = pp5::enumFromName<pp5::Projection>(c.projection);
  ps.render.compositing = {pp5::enumFromName<pp5::CompositeMode>(c.mode)};
  ps.render.threads = 2;
  ps.shading.mode = pp5::enumFromName<gp::ShadeMode>(c.shading);
  serial::SerialPipeline pipe(g, ps);
  const pp::CompositeMode mode = pp::compositeModeFromName(c.mode);

  std::size_t nonBlank = 0;
  auto expectFull = [&](const std::string& when) {
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
    ASSERT_EQ(differ, 0u) << when << ": " << differ << " channels differ, by up to " << worst;
    nonBlank = 0;
    for (std::size_t k = 0; k + 3 < inc.rgba.size(); k += 4)
      nonBlank += inc.rgba[k] + inc.rgba[k + 1] + inc.rgba[k + 2] > 0.0f ? 1 : 0;
  };
  for (std::size_t i = 0; i < sim.frameCount(); ++i) {
    const Frame f = sim.frame(i);
    pipe.insert(f, poses[i], f.timestamp);
    expectFull("frame " + std::to_string(i));
    if (HasFatalFailure()) return;
  }
  // Something was drawn: the doll's shell is in view.
  EXPECT_GT(nonBlank, 200u);

  // View changes re-light only the voxels that were visible: the shade
  // buffer equals a full re-shade for the new view, and the image a render
  // from scratch. Twice, so that the second starts from a view change's
  // shading; then one more frame.
  const TransferFunction tf(ps.tf);
  for (const double degrees : {35.0, -80.0}) {
    pipe.setCamera(pipe.camera().orbited(Vec3(0, 0, 1), degrees));
    gp::ShadeBuffer shade(g);
    gp::shade(pipe.reconstructor().output(), tf, pipe.settings().shading, pipe.camera(), gp::Box3{Index3(0), g.dims},
              shade);
    ASSERT_EQ(std::memcmp(shade.data(), pipe.shadeBuffer().data(), g.voxelCount() * sizeof(gp::ShadeVoxel)), 0)
        << "after turning by " << degrees << " degrees";
    expectFull("after turning by " + std::to_string(degrees) + " degrees");
    EXPECT_GT(nonBlank, 200u);
  }
  // A drag's coarse views: the pixels with rays are the full view's, bit
  // for bit, and every other pixel shows the one its block starts at; a
  // frame keeps the coarse image equal to a coarse render from scratch.
  const Camera cam = pipe.camera();
  for (const int stride : {2, 4}) {
    pipe.setCamera(cam);
    const pp::TileImage fine = pipe.image();
    const std::uint64_t fineSamples = pipe.cache().sampleCount();
    pipe.setCamera(cam, 1.0, stride);
    expectFull("a coarse view, stride " + std::to_string(stride));
    const pp::TileImage& coarse = pipe.image();
    for (int y = 0; y < coarse.height; ++y)
      for (int x = 0; x < coarse.width; ++x)
        ASSERT_EQ(std::memcmp(coarse.pixel(x, y), fine.pixel(x - x % stride, y - y % stride), 4 * sizeof(float)), 0)
            << "stride " << stride << " pixel " << x << " " << y;
    // Rays for one pixel in stride x stride: about that fraction of the samples.
    const double fraction = static_cast<double>(pipe.cache().sampleCount()) / static_cast<double>(fineSamples);
    EXPECT_GT(fraction * stride * stride, 0.7) << stride;
    EXPECT_LT(fraction * stride * stride, 1.4) << stride;
    const Frame f = sim.frame(1);
    pipe.insert(f, poses[1], f.timestamp + 50.0 + stride);
    expectFull("a frame in a coarse view, stride " + std::to_string(stride));
  }
  pipe.setCamera(cam);
  const Frame f = sim.frame(0);
  pipe.insert(f, poses[0], f.timestamp + 100.0);
  expectFull("a frame after the view changes");
}

INSTANTIATE_TEST_SUITE_P(Pipeline, IncrementalEqualsFull,
                         ::testing::Values(Case{"over", "phong", "perspective"}, Case{"over", "value", "perspective"},
                                           Case{"over", "phong", "orthographic"}, Case{"mip", "phong", "perspective"},
                                           Case{"mip", "value", "orthographic"},
                                           Case{"additive", "phong", "perspective"},
                                           Case{"additive", "value", "orthographic"}),
                         name);

}  // namespace

namespace {

using namespace pp5;

// A bright sphere of radius R in an empty 1 mm grid, value shading with a
// grey transfer function, MIP, orthographic: every pixel whose ray passes
// through the sphere's core shows the sphere's sample, the shade voxel's
// premultiplied colour after the opacity correction; the lit disc has the
// sphere's radius on screen.
// MIP and additive composite grey values: a sphere of value v shows v
// through the identity window whatever the transfer function and the step,
// and its additive image is v times the chord, also whatever the step.
TEST(AnalyticImage, MipOfABrightSphereHasItsValueAndRadius) {
  Grid g;
  g.dims = Index3(64);
  g.spacing = Vec3(1.0);
  g.origin = Vec3(-31.5);
  const double R = 15.0;
  for (const double value : {200.0, 77.0}) {
    Volume v;
    v.allocate(g, ScalarType::F32);
    for (std::int64_t k = 0; k < 64; ++k)
      for (std::int64_t j = 0; j < 64; ++j)
        for (std::int64_t i = 0; i < 64; ++i)
          v.setValue(g.linear(i, j, k), glm::length(g.voxelToWorld(Vec3(i, j, k))) <= R ? value : 0.0);

    // A transfer function that would hide the sphere: MIP must not care.
    TransferFunctionSettings tfs;
    tfs.opacity = {{0, 0, 0, 0}, {230, 0, 0, 0}, {231, 0.5, 0, 0}, {255, 0.5, 0, 0}};
    tfs.colour = {{0, 0, 0, 0}, {255, 1, 0.2, 0.2}};
    const TransferFunction tf(tfs);
    double additiveAtFirstStep = 0.0;
    for (const double step : {0.25, 0.5, 0.9, 1.7}) {
      for (const auto mode : {pp5::CompositeMode::Mip, pp5::CompositeMode::Additive}) {
        gp::ShadeSettings ss;  // Phong: MIP must not care either
        ss.greyValues = pp5::compositesGreyValues(mode);  // what the pipeline sets for a grey-value mode
        RenderSettings rs;
        rs.width = rs.height = 128;
        rs.projection = pp5::Projection::Orthographic;
        rs.compositing = {mode};
        rs.stepMm = step;
        rs.opacityUnitMm = 1.0;
        rs.azimuthDeg = 30.0;
        rs.elevationDeg = 20.0;
        const Camera cam = makeCamera(rs, g);
        gp::ShadeBuffer shade(g);
        gp::shade(v, tf, ss, cam, gp::Box3{Index3(0), g.dims}, shade);
        const SampleLattice lattice(cam, g, rs.step(g), rs.maxSamples, 2);
        pp::RayCacheSettings cs;
        cs.additiveScale = 1.0 / 64.0;  // the mean over 64 mm
        pp::RayCache cache(TileRect{0, 0, rs.width, rs.height}, rs.width, lattice.counts(), cs, mode, 2);
        gp::SampleCollector collect;
        gp::sampleAll(shade, lattice, rs, collect);
        const auto samples = collect.samples();
        cache.put(samples.data(), samples.size());
        cache.composite();
        const pp::TileImage& im = cache.image();
        const std::vector<std::uint8_t> rgb = pp::toRgb8(im);
        const std::size_t mid = (static_cast<std::size_t>(rs.height / 2) * rs.width + rs.width / 2) * 3;
        if (mode == pp5::CompositeMode::Mip) {
          // The displayed grey level is the sphere's value, exactly.
          EXPECT_EQ(rgb[mid], static_cast<int>(value)) << "step " << step;
          EXPECT_EQ(rgb[mid + 1], rgb[mid]);
          // The disc: pixels at least half as bright as the centre.
          const float centre = im.pixel(rs.width / 2, rs.height / 2)[0];
          const double mmPerPixel = cam.orthoHeightMm / rs.height;
          std::size_t lit = 0;
          for (int y = 0; y < rs.height; ++y)
            for (int x = 0; x < rs.width; ++x) lit += im.pixel(x, y)[0] >= 0.5f * centre ? 1 : 0;
          const double radiusPx = std::sqrt(static_cast<double>(lit) / 3.14159265358979323846);
          std::printf("MIP sphere of %g, step %.2f mm: centre %.2f, radius %.2f mm (R %.1f)\n", value, step,
                      255.0 * centre, radiusPx * mmPerPixel, R);
          EXPECT_NEAR(radiusPx * mmPerPixel, R, 1.0) << lit << " pixels lit";
        } else {
          // Additive at the centre: value x chord (2R, within a voxel) x scale, the same for every step.
          const double got = 255.0 * im.pixel(rs.width / 2, rs.height / 2)[0];
          EXPECT_NEAR(got, value * 2.0 * R / 64.0, value * 1.5 / 64.0) << "step " << step;
          if (additiveAtFirstStep == 0.0) additiveAtFirstStep = got;
          EXPECT_NEAR(got, additiveAtFirstStep, 0.03 * additiveAtFirstStep) << "step " << step;
        }
      }
    }
  }
}

}  // namespace
