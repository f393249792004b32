// Properties every reconstruction method must have, through the common
// interface: incremental equals batch (bitwise, any thread count), and the
// union of the dirty regions covers every voxel whose output changed.
#include <gtest/gtest.h>

#include <cstring>
#include <random>

#include "core/error.hpp"
#include "core/config.hpp"
#include "reconstruction/kernels.hpp"
#include "reconstruction/reconstruction.hpp"

namespace {

using pp5::Frame;
using pp5::Mat4;
using pp5::Vec3;

struct Sweep {
  std::vector<Frame> frames;
  std::vector<Mat4> poses;
  std::vector<double> times;
};

// A small tilted back-and-forth sweep of speckle-like 48x40 frames, 0.5 mm
// pixels, 1.5-3 mm apart, with a turn so that motion vectors trigger.
Sweep makeSweep(unsigned seed) {
  Sweep s;
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> px(0, 255);
  std::uniform_real_distribution<double> jitter(-0.3, 0.3);
  const int n = 14;
  for (int i = 0; i < n; ++i) {
    Frame f;
    f.allocate(48, 40, pp5::PixelType::U8);
    for (auto& p : f.pixels) p = static_cast<std::uint8_t>(px(rng));
    f.index = static_cast<std::uint64_t>(i);
    f.timestamp = 0.1 * i;
    // Forward for 8 frames, then back.
    const double x = i < 8 ? 2.0 * i : 2.0 * (15 - i) - 1.0;
    const Mat4 rot = pp5::rotationAxisAngle(glm::normalize(Vec3(0.2, 1.0, 0.1)), 0.25 + 0.02 * jitter(rng));
    const Mat4 pose = pp5::translation(Vec3(x + jitter(rng), 2.0, 1.0)) * rot *
                      pp5::rotationAxisAngle(Vec3(0, 0, 1), 1.5707963267948966) * pp5::scaling(Vec3(0.5, 0.5, 1.0));
    s.times.push_back(f.timestamp);
    s.frames.push_back(std::move(f));
    s.poses.push_back(pose);
  }
  return s;
}

pp5::Grid gridFor(const Sweep& s, const pp5::gp::ReconSettings& rs) {
  return pp5::gp::plusOutputGrid(s.poses, 48, 40, rs, Vec3(0.6));
}

struct Case {
  std::string name;
  pp5::gp::ReconSettings s;
};

std::vector<Case> cases() {
  std::vector<Case> out;
  for (const char* rep : {"accumulate", "motion_vector", "decay"}) {
    pp5::gp::ReconSettings s;
    s.method = pp5::gp::Method::Tent;
    s.tent.replacement = pp5::enumFromName<pp5::gp::Replacement>(rep);
    s.tent.decayTauS = 0.5;
    out.push_back({std::string("tent_") + rep, s});
  }
  for (const char* m : {"nearest", "trilinear"})
    for (const char* c : {"mean", "latest", "maximum"})
      for (const char* a : {"float", "plus"}) {
        pp5::gp::ReconSettings s;
        s.method = pp5::enumFromName<pp5::gp::Method>(m);
        s.pixel.compounding = pp5::enumFromName<pp5::gp::Compounding>(c);
        s.arithmetic = pp5::enumFromName<pp5::gp::Arithmetic>(a);
        out.push_back({std::string(m) + "_" + c + "_" + a, s});
      }
  pp5::gp::ReconSettings holes;
  holes.method = pp5::gp::Method::Nearest;
  holes.pixel.fillHoles = true;
  holes.pixel.fillHolesIncremental = true;
  out.push_back({"nearest_mean_holes_incremental", holes});
  return out;
}

class EveryMethod : public ::testing::TestWithParam<Case> {};

TEST_P(EveryMethod, IncrementalEqualsBatchAndDirtyRegionsCoverEveryChange) {
  const Sweep sw = makeSweep(11);
  pp5::gp::ReconSettings s1 = GetParam().s;
  s1.threads = 1;
  const pp5::Grid g = gridFor(sw, s1);
  auto inc = pp5::gp::makeReconstructor(g, s1);

  std::vector<float> before(g.voxelCount(), 0.0f);
  for (std::size_t f = 0; f < sw.frames.size(); ++f) {
    const auto r = inc->insert(sw.frames[f], sw.poses[f], sw.times[f]);
    const auto& out = inc->output();
    ASSERT_EQ(out.type, pp5::ScalarType::F32);
    const float* now = reinterpret_cast<const float*>(out.bytes.data());
    std::size_t changed = 0;
    for (std::int64_t k = 0; k < g.dims.z; ++k)
      for (std::int64_t j = 0; j < g.dims.y; ++j)
        for (std::int64_t i = 0; i < g.dims.x; ++i) {
          const std::size_t idx = g.linear(i, j, k);
          if (std::memcmp(&now[idx], &before[idx], sizeof(float)) == 0) continue;
          ++changed;
          ASSERT_TRUE(r.dirty.containsVoxel(i, j, k))
              << GetParam().name << ": frame " << f << " changed voxel " << i << "," << j << "," << k
              << " outside its dirty region";
        }
    EXPECT_GT(changed, 0u) << "frame " << f;
    std::memcpy(before.data(), now, before.size() * sizeof(float));
  }
  inc->finish();

  for (int threads : {2, 3}) {
    pp5::gp::ReconSettings sb = GetParam().s;
    sb.threads = threads;
    auto batch = pp5::gp::makeReconstructor(g, sb);
    for (std::size_t f = 0; f < sw.frames.size(); ++f) batch->insert(sw.frames[f], sw.poses[f], sw.times[f]);
    batch->finish();
    ASSERT_EQ(batch->output().bytes.size(), inc->output().bytes.size());
    EXPECT_EQ(std::memcmp(batch->output().bytes.data(), inc->output().bytes.data(), inc->output().bytes.size()), 0)
        << GetParam().name << ": " << threads << " threads, batch differs from incremental";
    const auto wa = batch->weights(), wb = inc->weights();
    EXPECT_EQ(wa.bytes, wb.bytes) << GetParam().name << ": weights differ";
  }
}

INSTANTIATE_TEST_SUITE_P(Reconstruction, EveryMethod, ::testing::ValuesIn(cases()),
                         [](const auto& info) { return info.param.name; });

TEST(Reconstruction, GridThatDoesNotFitIsRefusedBeforeAllocating) {
  pp5::Grid g;
  g.spacing = Vec3(0.01);
  g.dims = {7350, 7350, 7350};
  pp5::gp::ReconSettings s;
  try {
    pp5::gp::makeReconstructor(g, s, 0, "big.toml");
    FAIL();
  } catch (const pp5::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("big.toml"), std::string::npos) << e.what();
  }
}

TEST(Reconstruction, PlusOutputGridFollowsPlusRule) {
  // One frame, identity rotation, 0.5 mm pixels: corners span 0..(w-1)*0.5.
  const Mat4 pose = pp5::translation(Vec3(10, 20, 30)) * pp5::scaling(Vec3(0.5, 0.5, 1.0));
  pp5::gp::ReconSettings s;
  auto g = pp5::gp::plusOutputGrid({pose}, 101, 41, s, Vec3(1.0));
  EXPECT_EQ(g.origin, Vec3(10, 20, 30));
  EXPECT_EQ(g.dims, pp5::Index3(51, 21, 1));  // round(50/1)+1, round(20/1)+1, 0+1
  s.clipOrigin = {10, 4};
  s.clipSize = {20, 10};
  g = pp5::gp::plusOutputGrid({pose}, 101, 41, s, Vec3(0.5));
  EXPECT_EQ(g.origin, Vec3(15, 22, 30));
  EXPECT_EQ(g.dims, pp5::Index3(21, 11, 1));  // clip end is origin + size (no -1), as in PLUS
}

}  // namespace

namespace {

// The registry (reconstruction/kernels.hpp): every value of recon.method has one entry,
// under the name a file gives it, and every option an entry names is one the
// schema knows, so that what it tells the other stages is about real methods.
TEST(Kernels, EveryMethodIsRegisteredOnceUnderItsNameWithRealOptions) {
  using pp5::EnumNames;
  namespace gp = pp5::gp;
  const auto& names = EnumNames<gp::Method>::names;
  EXPECT_EQ(gp::kernels().size(), names.size());
  pp5::ConfigSchema schema;
  gp::ReconSettings rs;
  gp::registerOptions(schema, rs);
  const std::string doc = schema.markdown();
  for (const auto& [method, name] : names) {
    const gp::Kernel& k = gp::kernelFor(method);
    EXPECT_EQ(k.method, method);
    EXPECT_EQ(k.name, name);
    EXPECT_FALSE(k.summary.empty()) << name;
    EXPECT_FALSE(k.options.empty()) << name;
    for (const std::string_view o : k.options) EXPECT_NE(doc.find("`" + std::string(o) + "`"), std::string::npos) << o;
    gp::ReconSettings s;
    s.method = method;
    EXPECT_GT(k.bytesPerVoxel(s), 0u) << name;
    EXPECT_EQ(k.describe(s).rfind(std::string(name), 0), 0u) << k.describe(s);
  }
  // Only the tent kernel is bounded by the slice's reach, so only it can be windowed.
  EXPECT_TRUE(gp::kernelFor(gp::Method::Tent).windowed);
  EXPECT_FALSE(gp::kernelFor(gp::Method::Trilinear).windowed);
}

}  // namespace
