// The accuracy measures behind `pp5echo evaluate`: errors against a truth
// volume (with the swept region and the tissue subset), the swept region
// itself, leave-out sampling through held-out poses, and which voxels hold a
// value once hole filling has run.
#include <gtest/gtest.h>

#include <cmath>

#include "core/error.hpp"
#include "analysis/evaluation.hpp"
#include "reconstruction/reconstruction.hpp"

namespace {

using namespace pp5;
using namespace pp5::gp;

Grid smallGrid(Index3 dims, double spacing = 1.0) {
  Grid g;
  g.dims = dims;
  g.spacing = Vec3(spacing);
  g.origin = Vec3(0.0);
  return g;
}

Volume filled(const Grid& g, float v) {
  Volume out;
  out.allocate(g, ScalarType::F32);
  for (std::size_t i = 0; i < g.voxelCount(); ++i) out.setValue(i, v);
  return out;
}

TEST(Evaluation, TruthErrorsOverTheVoxelsWithAValueAndOverTissue) {
  const Grid g = smallGrid(Index3(4, 3, 2));  // 24 voxels
  Volume truth = filled(g, 7.0f);             // background (noise floor) 7
  truth.setValue(0, 100.0f);                  // two tissue voxels
  truth.setValue(1, 8.5f);
  Volume recon = filled(g, 7.0f);
  recon.setValue(0, 103.0f);  // +3 in tissue
  recon.setValue(1, 4.5f);    // -4 in tissue
  recon.setValue(2, 9.0f);    // +2 in the background
  recon.setValue(3, 50.0f);   // a voxel with no value: not compared
  auto covered = [](std::size_t i) { return i != 3 && i != 23; };
  const TruthMetrics m = compareWithTruth(recon, covered, truth, {});
  EXPECT_EQ(m.voxels, 24u);
  EXPECT_EQ(m.covered, 22u);
  EXPECT_EQ(m.compared, 22u);
  EXPECT_EQ(m.tissueCompared, 2u);
  EXPECT_NEAR(m.rmse, std::sqrt((9.0 + 16.0 + 4.0) / 22.0), 1e-9);
  EXPECT_NEAR(m.mae, (3.0 + 4.0 + 2.0) / 22.0, 1e-9);
  EXPECT_NEAR(m.rmseTissue, std::sqrt((9.0 + 16.0) / 2.0), 1e-9);
  EXPECT_NEAR(m.maeTissue, 3.5, 1e-9);
  EXPECT_NEAR(m.psnrDb, 20.0 * std::log10(255.0 / m.rmse), 1e-9);
  EXPECT_EQ(m.swept, 0u);

  // With a swept region: only voxels inside it count, holes inside it are counted.
  std::vector<std::uint8_t> swept(g.voxelCount(), 0);
  swept[0] = swept[2] = swept[3] = swept[23] = 1;
  const TruthMetrics s = compareWithTruth(recon, covered, truth, swept);
  EXPECT_EQ(s.swept, 4u);
  EXPECT_EQ(s.sweptHoles, 2u);
  EXPECT_DOUBLE_EQ(s.holeFraction(), 0.5);
  EXPECT_EQ(s.compared, 2u);
  EXPECT_NEAR(s.rmse, std::sqrt((9.0 + 4.0) / 2.0), 1e-9);
  EXPECT_NEAR(s.rmseTissue, 3.0, 1e-9);

  // A truth on another grid is refused.
  Grid other = g;
  other.origin.x = 0.5;
  Volume t2 = filled(other, 0.0f);
  EXPECT_THROW(compareWithTruth(recon, covered, t2, {}), InputError);
}

TEST(Evaluation, BackgroundSplitsIntoTheEdgeOfTissueAndTheRest) {
  // A 9 x 7 x 5 grid of 1 mm with one tissue voxel in the middle (4, 3, 2):
  // with a 2 mm edge, the background voxels in the 5 x 5 x 5 box around it
  // (clipped to the grid) are its edge, the others far from it.
  const Grid g = smallGrid(Index3(9, 7, 5));
  Volume truth = filled(g, 5.0f);
  const std::size_t centre = g.linear(4, 3, 2);
  truth.setValue(centre, 120.0f);
  Volume recon = filled(g, 5.0f);
  recon.setValue(centre, 110.0f);           // -10 in tissue
  recon.setValue(g.linear(6, 1, 0), 9.0f);  // +4 on the box's corner: edge
  recon.setValue(g.linear(2, 3, 2), 2.0f);  // -3 two voxels along x: edge
  recon.setValue(g.linear(7, 3, 2), 11.0f); // +6 three voxels along x: far
  recon.setValue(g.linear(4, 6, 4), 3.0f);  // -2 three along y: far
  auto all = [](std::size_t) { return true; };
  const TruthMetrics m = compareWithTruth(recon, all, truth, {}, 2.0);
  EXPECT_EQ(m.edgeMm, 2.0);
  EXPECT_EQ(m.tissueCompared, 1u);
  EXPECT_EQ(m.edgeCompared, 5u * 5u * 5u - 1u);
  EXPECT_EQ(m.farCompared, g.voxelCount() - 5u * 5u * 5u);
  EXPECT_NEAR(m.rmseTissue, 10.0, 1e-9);
  EXPECT_NEAR(m.rmseEdge, std::sqrt((16.0 + 9.0) / 124.0), 1e-9);
  EXPECT_NEAR(m.biasEdge, (4.0 - 3.0) / 124.0, 1e-9);
  EXPECT_NEAR(m.rmseFar, std::sqrt((36.0 + 4.0) / static_cast<double>(m.farCompared)), 1e-9);
  EXPECT_NEAR(m.bias, (-10.0 + 4.0 - 3.0 + 6.0 - 2.0) / static_cast<double>(g.voxelCount()), 1e-9);

  // The edge is in mm: 2 mm voxels along x reach one voxel that way.
  Grid wide = g;
  wide.spacing.x = 2.0;
  Volume tw = truth, rw = recon;
  tw.grid = rw.grid = wide;
  const TruthMetrics w = compareWithTruth(rw, all, tw, {}, 2.0);
  EXPECT_EQ(w.edgeCompared, 3u * 5u * 5u - 1u);
  // (6, 1, 0) and (2, 3, 2) are two voxels, 4 mm, along x: now far.
  EXPECT_EQ(w.rmseEdge, 0.0);
  EXPECT_NEAR(w.rmseFar, std::sqrt((16.0 + 9.0 + 36.0 + 4.0) / static_cast<double>(w.farCompared)), 1e-9);

  // No edge: every background voxel is far.
  const TruthMetrics z = compareWithTruth(recon, all, truth, {}, 0.0);
  EXPECT_EQ(z.edgeCompared, 0u);
  EXPECT_EQ(z.farCompared, g.voxelCount() - 1u);
}

TEST(Evaluation, SweptRegionIsBetweenConsecutiveFramesAndInsideThem) {
  // Frames of 11 x 6 pixels, 1 mm pixels, in planes x = 2 and x = 6, the image
  // spanning y 1..11 and z 2..7.
  const Grid g = smallGrid(Index3(10, 14, 10));
  auto pose = [](double x) {
    Mat4 m(1.0);
    m[0] = Vec4(0, 1, 0, 0);  // image x -> +y
    m[1] = Vec4(0, 0, 1, 0);  // image y -> +z
    m[2] = Vec4(1, 0, 0, 0);
    m[3] = Vec4(x, 1, 2, 1);
    return m;
  };
  const auto mask = sweptRegion(g, {pose(2.0), pose(6.0)}, 11, 6);
  auto at = [&](int x, int y, int z) { return mask[g.linear(x, y, z)] != 0; };
  for (int x = 0; x < 10; ++x) EXPECT_EQ(at(x, 5, 4), x >= 2 && x <= 6) << x;
  EXPECT_TRUE(at(4, 1, 2));
  EXPECT_TRUE(at(4, 11, 7));
  EXPECT_FALSE(at(4, 0, 4));   // beside the image
  EXPECT_FALSE(at(4, 12, 4));
  EXPECT_FALSE(at(4, 5, 1));   // above it
  EXPECT_FALSE(at(4, 5, 8));   // below it
}

TEST(Evaluation, LeaveOutSamplesThroughThePoseAndOnlyInsideTheMask) {
  // A volume whose value is 10 + 2x + 3y + 5z (trilinear sampling is exact).
  const Grid g = smallGrid(Index3(12, 12, 12));
  Volume v;
  v.allocate(g, ScalarType::F32);
  for (int z = 0; z < 12; ++z)
    for (int y = 0; y < 12; ++y)
      for (int x = 0; x < 12; ++x) v.setValue(g.linear(x, y, z), static_cast<float>(10 + 2 * x + 3 * y + 5 * z));
  // A held-out 8 x 6 frame at an oblique pose, 0.7 mm pixels.
  const Mat4 pose = translation(Vec3(2.2, 1.7, 2.9)) * rotationAxisAngle(glm::normalize(Vec3(1, 2, 3)), 0.4) *
                    scaling(Vec3(0.7, 0.7, 1.0));
  Frame f;
  f.allocate(8, 6, PixelType::U8);
  for (int y = 0; y < 6; ++y)
    for (int x = 0; x < 8; ++x) {
      const Vec3 p = transformPoint(pose, Vec3(x, y, 0));
      f.u8()[y * 8 + x] = static_cast<std::uint8_t>(std::lround(10 + 2 * p.x + 3 * p.y + 5 * p.z));
    }
  // Only rows 1..4, columns 2..6 are in the mask.
  std::vector<PixelRun> runs;
  for (int y = 1; y <= 4; ++y) runs.push_back({y, 2, 6});
  auto all = [](std::size_t) { return true; };
  LeaveOutMetrics m;
  compareHeldOutFrame(v, all, f, pose, runs, m);
  m.finish();
  EXPECT_EQ(m.framesHeldOut, 1u);
  EXPECT_EQ(m.pixelsCompared, 20u);
  EXPECT_EQ(m.pixelsSkipped, 0u);
  EXPECT_LE(m.mae, 0.5);  // only the rounding of the pixels to integers
  EXPECT_LE(m.rmse, 0.5);

  // A pixel whose trilinear neighbourhood holds a voxel with no value is skipped.
  const Vec3 p = g.worldToVoxel(transformPoint(pose, Vec3(4, 2, 0)));
  const std::size_t hole = g.linear(static_cast<std::int64_t>(std::floor(p.x)), static_cast<std::int64_t>(std::floor(p.y)),
                                    static_cast<std::int64_t>(std::floor(p.z)));
  auto notHole = [hole](std::size_t i) { return i != hole; };
  LeaveOutMetrics h;
  compareHeldOutFrame(v, notHole, f, pose, runs, h);
  EXPECT_GE(h.pixelsSkipped, 1u);
  EXPECT_EQ(h.pixelsCompared + h.pixelsSkipped, 20u);
}

// PLUS's reading of a held-out pixel: the trilinear value rounded to a grey
// level, and a pixel whose value rounds to 0 not compared.
TEST(Evaluation, LeaveOutPlusReadingRoundsAndSkipsZero) {
  const Grid g = smallGrid(Index3(8, 8, 8));
  Volume v;
  v.allocate(g, ScalarType::F32);
  // x < 4: 0.4 (rounds to 0); x >= 4: 7.4 (rounds to 7).
  for (int z = 0; z < 8; ++z)
    for (int y = 0; y < 8; ++y)
      for (int x = 0; x < 8; ++x) v.setValue(g.linear(x, y, z), x < 4 ? 0.4f : 7.4f);
  // A 7 x 1 frame along x at voxel rows y = z = 3, pixel x at voxel x: all 8
  // neighbours of pixel x lie in columns x and x + 1.
  const Mat4 pose = translation(g.voxelToWorld(Vec3(0, 3, 3))) * scaling(Vec3(g.spacing.x, 1.0, 1.0));
  Frame f;
  f.allocate(7, 1, PixelType::U8);
  for (int x = 0; x < 7; ++x) f.u8()[x] = 5;
  const std::vector<PixelRun> runs = {{0, 0, 6}};
  auto all = [](std::size_t) { return true; };
  LeaveOutMetrics tri, plus;
  compareHeldOutFrame(v, all, f, pose, runs, tri, LeaveOutReading::Trilinear);
  compareHeldOutFrame(v, all, f, pose, runs, plus, LeaveOutReading::PlusGreyLevels);
  tri.finish();
  plus.finish();
  EXPECT_EQ(tri.pixelsCompared, 7u);  // every pixel has its 8 neighbours
  // Pixels 0..3 read 0.4 (0 once rounded): skipped; 4..6 read 7.4, rounded to 7.
  EXPECT_EQ(plus.pixelsCompared, 3u);
  EXPECT_EQ(plus.pixelsSkipped, 4u);
  EXPECT_DOUBLE_EQ(plus.bias, 2.0);
  EXPECT_NEAR(tri.bias, (4 * (0.4 - 5) + 3 * (7.4 - 5)) / 7.0, 1e-6);  // float voxels
}

// Two frames 6 mm apart into a 1 mm grid: nearest neighbour leaves the voxels
// between them empty; hole filling gives them values, and hasValue says so.
TEST(Evaluation, HoleFilledVoxelsHaveAValueButAreNotCovered) {
  auto pose = [](double x) {
    Mat4 m(1.0);
    m[0] = Vec4(0, 1, 0, 0);
    m[1] = Vec4(0, 0, 1, 0);
    m[2] = Vec4(1, 0, 0, 0);
    m[3] = Vec4(x, 1, 1, 1);
    return m;
  };
  const Grid g = smallGrid(Index3(12, 10, 10));
  Frame f;
  f.allocate(8, 8, PixelType::U8);
  for (auto& px : f.pixels) px = 90;
  for (bool fill : {false, true}) {
    ReconSettings s;
    s.method = pp5::gp::Method::Nearest;
    s.pixel.fillHoles = fill;
    auto r = makeReconstructor(g, s);
    r->insert(f, pose(2.0), 0.0);
    r->insert(f, pose(8.0), 0.1);
    r->finish();
    const std::size_t between = g.linear(5, 4, 4), far = g.linear(5, 9, 9), onFrame = g.linear(2, 4, 4);
    EXPECT_TRUE(r->covered(onFrame));
    EXPECT_TRUE(r->hasValue(onFrame));
    EXPECT_FALSE(r->covered(between));
    EXPECT_EQ(r->hasValue(between), fill);
    if (fill) {
      EXPECT_FLOAT_EQ(r->output().value(between), 90.0f);
    }
    // Far outside the frames no kernel reaches: no value, filled or not.
    EXPECT_FALSE(r->hasValue(far));
    EXPECT_EQ(r->output().value(far), 0.0);
  }
}

}  // namespace
