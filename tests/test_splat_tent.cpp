// The 1990 paper's reconstruction: tent kernel, fill-in, replacement, and the
// incremental / deterministic guarantees. Frames are synthetic and small, so
// every expected value is computed here from the definitions.
#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <numbers>
#include <random>
#include <sstream>
#include <vector>

#include "core/error.hpp"
#include "core/transform.hpp"
#include "reconstruction/fan_mask.hpp"
#include "reconstruction/splat_tent.hpp"
#include "sim/simulate.hpp"

namespace pp5::gp {
namespace {

using PixelFn = std::function<double(int, int)>;

Frame makeFrame(int w, int h, const PixelFn& fn, PixelType type = PixelType::U8) {
  Frame f;
  f.allocate(w, h, type);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const auto v = static_cast<std::uint32_t>(std::lround(fn(x, y)));
      const std::size_t i = static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x);
      if (type == PixelType::U8) {
        f.pixels[i] = static_cast<std::uint8_t>(std::min<std::uint32_t>(v, 255));
      } else {
        f.pixels[2 * i] = static_cast<std::uint8_t>(v & 0xff);
        f.pixels[2 * i + 1] = static_cast<std::uint8_t>((v >> 8) & 0xff);
      }
    }
  return f;
}

Frame constantFrame(int w, int h, double v, PixelType type = PixelType::U8) {
  return makeFrame(w, h, [v](int, int) { return v; }, type);
}

glm::dmat3 rot(const Vec3& axis, double radians) { return glm::dmat3(rotationAxisAngle(axis, radians)); }

// ImageToReference: pixel (x, y) -> origin + x*sx*R[0] + y*sy*R[1].
Mat4 imagePose(const Vec3& origin, const glm::dmat3& r, double sx, double sy) {
  Mat4 m(1.0);
  m[0] = Vec4(r[0] * sx, 0.0);
  m[1] = Vec4(r[1] * sy, 0.0);
  m[2] = Vec4(r[2], 0.0);
  m[3] = Vec4(origin, 1.0);
  return m;
}

// The pose that puts the image's centre at `centre`.
Mat4 centredPose(const Vec3& centre, const glm::dmat3& r, double sx, double sy, int w, int h) {
  return imagePose(centre - r[0] * (sx * (w - 1) * 0.5) - r[1] * (sy * (h - 1) * 0.5), r, sx, sy);
}

Grid cubeGrid(std::int64_t n, double spacing) {
  Grid g;
  g.dims = Index3(n);
  g.spacing = Vec3(spacing);
  g.origin = Vec3(-(static_cast<double>(n) - 1.0) * 0.5 * spacing);
  return g;
}

// The kernel most tests here were written for (1.0 x 0.75 x 1.5 mm, once the
// default): their counts of fill-in slices, covered voxels and dirty voxels
// follow from it, so it is pinned here and the tests check the algorithm
// rather than whatever the default happens to be. Tests that need another
// kernel set it themselves.
ReconSettings baseSettings() {
  ReconSettings s;
  s.threads = 1;
  s.tent.kernelLateralMm = 1.0;
  s.tent.kernelAxialMm = 0.75;
  s.tent.kernelElevationMm = 1.5;
  return s;
}

double tent(double t) { return std::max(0.0, 1.0 - std::abs(t)); }

float f32(const Volume& v, std::size_t i) {
  float x;
  std::memcpy(&x, v.bytes.data() + 4 * i, sizeof x);
  return x;
}

Vec3 voxelCentre(const Grid& g, std::int64_t i, std::int64_t j, std::int64_t k) {
  return g.voxelToWorld(Vec3(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)));
}

// The literal forward mapping: every selected pixel's tent weight at voxel x.
struct Forward {
  double w = 0.0, wv = 0.0;
};
Forward forwardSum(const Mat4& m, const Frame& f, const Vec3& x, double hl, double ha, double he,
                   const std::function<bool(int, int)>& selected) {
  const Vec3 ex(m[0]), ey(m[1]);
  const Vec3 u = glm::normalize(ex), n = glm::normalize(glm::cross(ex, ey)), v = glm::cross(n, u);
  Forward s;
  for (int y = 0; y < f.height; ++y)
    for (int px = 0; px < f.width; ++px) {
      if (!selected(px, y)) continue;
      const Vec3 p = transformPoint(m, Vec3(px, y, 0));
      const Vec3 d = x - p;
      const double w = tent(glm::dot(d, u) / hl) * tent(glm::dot(d, v) / ha) * tent(glm::dot(d, n) / he);
      s.w += w;
      s.wv += w * f.value(px, y);
    }
  return s;
}

// --------------------------------------------------------------- values --

class TentConstant : public ::testing::TestWithParam<PixelType> {};

TEST_P(TentConstant, ConstantImageReconstructsToTheConstant) {
  const double c = GetParam() == PixelType::U8 ? 200.0 : 1000.0;
  const Grid g = cubeGrid(40, 1.0);
  ReconSettings s = baseSettings();
  auto rec = makeTentReconstructor(g, s);
  const int w = 30, h = 20;
  const Frame f = constantFrame(w, h, c, GetParam());
  int fillIns = 0;
  for (int i = 0; i < 6; ++i) {
    const glm::dmat3 r = rot(Vec3(1, 2, 3), 0.4 + 0.03 * i);
    const Vec3 centre = r[2] * (2.5 * (i - 2.5));
    fillIns += rec->insert(f, centredPose(centre, r, 0.8, 1.1, w, h), 0.1 * i).fillInSlices;
  }
  EXPECT_GT(fillIns, 0);
  const Volume& out = rec->output();
  std::size_t covered = 0;
  for (std::size_t i = 0; i < g.voxelCount(); ++i) {
    if (!rec->covered(i)) {
      ASSERT_EQ(f32(out, i), 0.0f) << "voxel " << i << " is not covered but has a value";
      continue;
    }
    ++covered;
    ASSERT_NEAR(f32(out, i), c, c * 1e-5) << "voxel " << i;
  }
  EXPECT_GT(covered, 5000u);
}

INSTANTIATE_TEST_SUITE_P(PixelTypes, TentConstant, ::testing::Values(PixelType::U8, PixelType::U16));

// One pixel (the others rejected as too dark): weights() is the tent product.
class TentKernel : public ::testing::TestWithParam<int> {};

TEST_P(TentKernel, WeightsAreTheTentProductInTheSlicesAxes) {
  const Grid g = cubeGrid(24, 0.5);
  ReconSettings s = baseSettings();
  s.tent.kernelLateralMm = 1.7;
  s.tent.kernelAxialMm = 0.9;
  s.tent.kernelElevationMm = 1.2;
  s.pixelRejectionThreshold = 1.0;
  const glm::dmat3 r = GetParam() == 0 ? glm::dmat3(1.0) : rot(Vec3(1, -2, 0.5), 0.9);
  const double sx = 0.7, sy = 0.45;
  const Vec3 p(0.13, -0.21, 0.07);  // where pixel (1, 1) lands, between voxel centres
  const Mat4 m = imagePose(p - r[0] * sx - r[1] * sy, r, sx, sy);
  const Frame f = makeFrame(3, 3, [](int x, int y) { return x == 1 && y == 1 ? 200.0 : 0.0; });
  auto rec = makeTentReconstructor(g, s);
  EXPECT_EQ(rec->insert(f, m, 0.0).pixelsInserted, 1u);

  const Volume wv = rec->weights();
  std::size_t nonzero = 0;
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j)
      for (std::int64_t i = 0; i < g.dims.x; ++i) {
        const Vec3 d = voxelCentre(g, i, j, k) - p;
        const double expected =
            tent(glm::dot(d, r[0]) / 1.7) * tent(glm::dot(d, r[1]) / 0.9) * tent(glm::dot(d, r[2]) / 1.2);
        const std::size_t li = g.linear(i, j, k);
        ASSERT_NEAR(f32(wv, li), expected, 1e-6) << i << " " << j << " " << k;
        if (expected > 1e-9) {
          ++nonzero;
          ASSERT_TRUE(rec->covered(li));
          ASSERT_NEAR(f32(rec->output(), li), 200.0, 2e-3);
        } else if (expected == 0.0) {
          ASSERT_FALSE(rec->covered(li));
        }
      }
  // The support is 3.4 x 1.8 x 2.4 mm: about 118 voxels of 0.5 mm.
  EXPECT_GT(nonzero, 60u);
}

INSTANTIATE_TEST_SUITE_P(Poses, TentKernel, ::testing::Values(0, 1));

// Many pixels, clip rectangle, rejection and fan: the reconstruction equals
// the literal per-pixel forward mapping over the pixels the pixel methods
// select (PLUS's clip rectangle, end included; the fan of fan_mask.hpp) that
// are not darker than the rejection threshold.
TEST(TentKernel, EqualsThePerPixelForwardMapping) {
  const Grid g = cubeGrid(24, 0.6);
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> dist(0, 255);
  std::vector<int> vals(8 * 8);
  for (int& v : vals) v = dist(rng);
  const Frame f = makeFrame(8, 8, [&](int x, int y) { return vals[static_cast<std::size_t>(y * 8 + x)]; });
  const glm::dmat3 r = rot(Vec3(0.3, 1, -0.7), 1.1);
  const Mat4 m = centredPose(Vec3(0.2, -0.1, 0.3), r, 0.55, 0.8, 8, 8);

  auto setFan = [](ReconSettings& s) {
    s.fanAnglesDeg = {-40.0, 30.0};
    s.fanOriginPx = {3.5, -2.0};
    s.fanRadiusStartPx = 3.0;
    s.fanRadiusStopPx = 9.0;
  };
  ReconSettings fanSettings;
  setFan(fanSettings);
  const std::vector<PixelRun> fanRuns = pixelRuns(8, 8, fanSettings);
  auto inRuns = [](const std::vector<PixelRun>& runs, int x, int y) {
    for (const PixelRun& r : runs)
      if (r.y == y && x >= r.x0 && x <= r.x1) return true;
    return false;
  };
  struct Case {
    const char* name;
    std::function<void(ReconSettings&)> set;
    std::function<bool(int, int)> selected;
  };
  const std::vector<Case> cases = {
      {"all", [](ReconSettings&) {}, [](int, int) { return true; }},
      {"clip",
       [](ReconSettings& s) {
         s.clipOrigin = {2, 3};
         s.clipSize = {3, 4};
       },
       [](int x, int y) { return x >= 2 && x <= 5 && y >= 3 && y <= 7; }},
      {"clip_and_reject",
       [](ReconSettings& s) {
         s.clipOrigin = {1, 1};
         s.clipSize = {5, 5};
         s.pixelRejectionThreshold = 80;
       },
       [&](int x, int y) { return x >= 1 && x <= 6 && y >= 1 && y <= 6 && vals[static_cast<std::size_t>(y * 8 + x)] >= 80; }},
      {"reject", [](ReconSettings& s) { s.pixelRejectionThreshold = 100; },
       [&](int x, int y) { return vals[static_cast<std::size_t>(y * 8 + x)] >= 100; }},
      {"fan", setFan, [&](int x, int y) { return inRuns(fanRuns, x, y); }},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    ReconSettings s = baseSettings();
    s.tent.kernelLateralMm = 1.3;
    s.tent.kernelAxialMm = 0.7;
    s.tent.kernelElevationMm = 1.1;
    c.set(s);
    std::uint64_t expectedPixels = 0;
    for (int y = 0; y < 8; ++y)
      for (int x = 0; x < 8; ++x) expectedPixels += c.selected(x, y) ? 1 : 0;
    ASSERT_GT(expectedPixels, 3u);
    ASSERT_LT(std::string(c.name) == "all" ? 0u : expectedPixels, 64u);
    auto rec = makeTentReconstructor(g, s);
    EXPECT_EQ(rec->insert(f, m, 0.0).pixelsInserted, expectedPixels);
    const Volume wv = rec->weights();
    std::size_t checked = 0;
    for (std::int64_t k = 0; k < g.dims.z; ++k)
      for (std::int64_t j = 0; j < g.dims.y; ++j)
        for (std::int64_t i = 0; i < g.dims.x; ++i) {
          const Forward e = forwardSum(m, f, voxelCentre(g, i, j, k), 1.3, 0.7, 1.1, c.selected);
          const std::size_t li = g.linear(i, j, k);
          ASSERT_NEAR(f32(wv, li), e.w, 1e-5 * std::max(1.0, e.w)) << i << " " << j << " " << k;
          if (e.w > 1e-4) {
            ++checked;
            ASSERT_NEAR(f32(rec->output(), li), e.wv / e.w, 2e-3) << i << " " << j << " " << k;
          }
        }
    EXPECT_GT(checked, 100u);
  }
}

// Kernels and pixel grids of every shape the implementation treats apart:
// sheared pixel axes (by much, and by a calibration's fraction of a pixel),
// lateral windows of up to 4 and of more than 8 pixels, and axial windows of
// more than 32 rows, all against the literal sum.
struct ShapeCase {
  const char* name;
  int w, h;
  double sx, sy, shear;  // image y axis = sy * (R[1] + shear * R[0])
  double hl, ha, he;
  double threshold;  // pixel rejection, < 0 = off
};

class TentShapes : public ::testing::TestWithParam<ShapeCase> {};

TEST_P(TentShapes, EqualsThePerPixelForwardMapping) {
  const ShapeCase& c = GetParam();
  const Grid g = cubeGrid(20, 0.6);
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> dist(0, 255);
  std::vector<int> vals(static_cast<std::size_t>(c.w * c.h));
  for (int& v : vals) v = dist(rng);
  const Frame f = makeFrame(c.w, c.h, [&](int x, int y) { return vals[static_cast<std::size_t>(y * c.w + x)]; });
  const glm::dmat3 r = rot(Vec3(0.5, -1, 0.3), 0.7);
  Mat4 m = centredPose(Vec3(0.1, 0.2, -0.15), r, c.sx, c.sy, c.w, c.h);
  m[1] = Vec4((r[1] + c.shear * r[0]) * c.sy, 0.0);
  m[3] = Vec4(Vec3(0.1, 0.2, -0.15) - Vec3(m[0]) * (0.5 * (c.w - 1)) - Vec3(m[1]) * (0.5 * (c.h - 1)), 1.0);
  ReconSettings s = baseSettings();
  s.tent.kernelLateralMm = c.hl;
  s.tent.kernelAxialMm = c.ha;
  s.tent.kernelElevationMm = c.he;
  s.pixelRejectionThreshold = c.threshold;
  auto selected = [&](int x, int y) { return c.threshold < 0 || vals[static_cast<std::size_t>(y * c.w + x)] >= c.threshold; };
  auto rec = makeTentReconstructor(g, s);
  rec->insert(f, m, 0.0);
  const Volume wv = rec->weights();
  std::size_t checked = 0;
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j)
      for (std::int64_t i = 0; i < g.dims.x; ++i) {
        const Forward e = forwardSum(m, f, voxelCentre(g, i, j, k), c.hl, c.ha, c.he, selected);
        const std::size_t li = g.linear(i, j, k);
        ASSERT_NEAR(f32(wv, li), e.w, 2e-5 * std::max(1.0, e.w)) << i << " " << j << " " << k;
        if (e.w > 1e-3) {
          ++checked;
          ASSERT_NEAR(f32(rec->output(), li), e.wv / e.w, 2e-3) << i << " " << j << " " << k;
        }
      }
  EXPECT_GT(checked, 50u);
}

INSTANTIATE_TEST_SUITE_P(
    Shapes, TentShapes,
    ::testing::Values(ShapeCase{"sheared", 9, 7, 0.5, 0.6, 0.35, 1.1, 0.8, 1.0, -1.0},
                      ShapeCase{"sheared_rejecting", 9, 7, 0.5, 0.6, -0.2, 1.1, 0.8, 1.0, 90.0},
                      ShapeCase{"four_taps", 7, 7, 0.9, 0.7, 0.0, 1.2, 0.8, 1.0, -1.0},
                      ShapeCase{"many_taps", 30, 5, 0.15, 0.9, 0.0, 1.9, 1.0, 1.0, -1.0},
                      ShapeCase{"many_taps_rejecting", 30, 5, 0.15, 0.9, 0.0, 1.9, 1.0, 1.0, 60.0},
                      ShapeCase{"tall_window", 5, 60, 0.9, 0.1, 0.0, 1.0, 2.0, 1.0, -1.0},
                      ShapeCase{"tall_sheared_window", 5, 60, 0.9, 0.1, 0.3, 1.0, 2.0, 1.0, 40.0},
                      // A calibration's shear (fCal 2.0's: -0.006 of a row's height): the
                      // rows of most axial windows share their knot cell.
                      ShapeCase{"calibration_shear", 40, 60, 0.1, 0.08, -0.006, 1.0, 0.8, 1.0, -1.0},
                      ShapeCase{"calibration_shear_rejecting", 40, 60, 0.1, 0.08, 0.006, 1.0, 0.8, 1.0, 70.0}),
    [](const ::testing::TestParamInfo<ShapeCase>& i) { return std::string(i.param.name); });

// Random images with pixels left out (a clip rectangle, rejection of random
// dark pixels and of a dark block wider than the kernel), in poses that take
// each of the implementation's paths (a slice facing grid x, one whose axial
// axis is perpendicular to grid x, a tilted one, random ones, a sheared one),
// with half-widths that are not multiples of the pixel spacing and some that
// are, against a double-precision scatter of every selected pixel.
struct ScatterCase {
  const char* name;
  double sx, sy, shear;  // image y axis = sy * (R[1] + shear * R[0])
  double hl, ha, he;
  int pose;  // 0: facing grid x, 1: yawed 30 degrees, 2: tilted 15 degrees, else random
};

void PrintTo(const ScatterCase& c, std::ostream* os) { *os << c.name; }

class TentScatter : public ::testing::TestWithParam<ScatterCase> {};

TEST_P(TentScatter, EqualsADoublePrecisionScatter) {
  const ScatterCase& c = GetParam();
  const int w = 31, h = 15;
  const Grid g = cubeGrid(32, 0.5);
  std::mt19937 rng(1990 + static_cast<unsigned>(c.pose));
  std::uniform_int_distribution<int> dist(0, 255);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  std::vector<int> vals(static_cast<std::size_t>(w * h));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      vals[static_cast<std::size_t>(y * w + x)] = x >= 12 && x <= 23 && y >= 4 && y <= 10 ? 5 : dist(rng);
  const Frame f = makeFrame(w, h, [&](int x, int y) { return vals[static_cast<std::size_t>(y * w + x)]; });

  // The simulated probe looks down: lateral -y, axial -z, elevation +x.
  const glm::dmat3 probe(Vec3(0, -1, 0), Vec3(0, 0, -1), Vec3(1, 0, 0));
  glm::dmat3 r = probe;
  if (c.pose == 1) r = rot(Vec3(0, 0, 1), glm::radians(30.0)) * probe;
  if (c.pose == 2) r = rot(Vec3(0, 1, 0), glm::radians(15.0)) * probe;
  if (c.pose > 2) r = rot(Vec3(uni(rng), uni(rng), uni(rng)) + Vec3(0.0, 0.0, 1e-3), 3.0 * uni(rng));
  const Vec3 centre(0.4 * uni(rng), 0.4 * uni(rng), 0.4 * uni(rng));
  Mat4 m = imagePose(Vec3(0.0), r, c.sx, c.sy);
  m[1] = Vec4((r[1] + c.shear * r[0]) * c.sy, 0.0);
  m[3] = Vec4(centre - Vec3(m[0]) * (0.5 * (w - 1)) - Vec3(m[1]) * (0.5 * (h - 1)), 1.0);

  ReconSettings s = baseSettings();
  s.tent.kernelLateralMm = c.hl;
  s.tent.kernelAxialMm = c.ha;
  s.tent.kernelElevationMm = c.he;
  s.clipOrigin = {1, 0};
  s.clipSize = {28, 13};
  s.pixelRejectionThreshold = 30;
  const std::vector<PixelRun> runs = pixelRuns(w, h, s);
  auto selected = [&](int x, int y) {
    for (const PixelRun& run : runs)
      if (run.y == y && x >= run.x0 && x <= run.x1) return vals[static_cast<std::size_t>(y * w + x)] >= 30;
    return false;
  };

  // The scatter, over the voxels within the kernel's reach of each pixel.
  const Vec3 u = glm::normalize(Vec3(m[0])), n = glm::normalize(glm::cross(Vec3(m[0]), Vec3(m[1])));
  const Vec3 v = glm::cross(n, u);
  std::vector<double> sw(g.voxelCount(), 0.0), swv(g.voxelCount(), 0.0);
  std::uint64_t pixels = 0;
  const double reach = std::sqrt(c.hl * c.hl + c.ha * c.ha + c.he * c.he) / g.spacing.x + 1.0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      if (!selected(x, y)) continue;
      ++pixels;
      const Vec3 p = transformPoint(m, Vec3(x, y, 0));
      const Vec3 pv = g.worldToVoxel(p);
      const Index3 lo(glm::max(glm::floor(pv - reach), Vec3(0.0))), hi(glm::min(glm::ceil(pv + reach), Vec3(g.dims - Index3(1))));
      for (std::int64_t k = lo.z; k <= hi.z; ++k)
        for (std::int64_t j = lo.y; j <= hi.y; ++j)
          for (std::int64_t i = lo.x; i <= hi.x; ++i) {
            const Vec3 d = voxelCentre(g, i, j, k) - p;
            const double wt = tent(glm::dot(d, u) / c.hl) * tent(glm::dot(d, v) / c.ha) * tent(glm::dot(d, n) / c.he);
            sw[g.linear(i, j, k)] += wt;
            swv[g.linear(i, j, k)] += wt * vals[static_cast<std::size_t>(y * w + x)];
          }
    }

  auto rec = makeTentReconstructor(g, s);
  EXPECT_EQ(rec->insert(f, m, 0.0).pixelsInserted, pixels);
  const Volume wv = rec->weights();
  const Mat4 toPixel = glm::inverse(m);
  std::size_t checked = 0, holes = 0;
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j)
      for (std::int64_t i = 0; i < g.dims.x; ++i) {
        const std::size_t li = g.linear(i, j, k);
        const double ew = sw[li];
        ASSERT_NEAR(f32(wv, li), ew, 1e-5 * std::max(1.0, ew)) << i << " " << j << " " << k;
        if (ew == 0.0) {
          ASSERT_FALSE(rec->covered(li)) << i << " " << j << " " << k;
          // Inside the image's rectangle, near its plane: under the dark block.
          const Vec3 px = transformPoint(toPixel, voxelCentre(g, i, j, k));
          holes += px.x > 0.0 && px.x < w - 1 && px.y > 0.0 && px.y < h - 1 && std::abs(px.z) < 0.5 * c.he ? 1 : 0;
        }
        if (ew > 1e-6) {
          ASSERT_TRUE(rec->covered(li)) << i << " " << j << " " << k;
        }
        if (ew > 1e-3) {
          ++checked;
          ASSERT_NEAR(f32(rec->output(), li), swv[li] / ew, 2e-3) << i << " " << j << " " << k;
        }
      }
  EXPECT_GT(checked, 500u);
  EXPECT_GT(holes, 0u) << "no voxel under the dark block was checked";
}

INSTANTIATE_TEST_SUITE_P(
    Poses, TentScatter,
    ::testing::Values(ScatterCase{"facing_x", 0.41, 0.37, 0.0, 1.37, 0.83, 1.1, 0},
                      ScatterCase{"yawed", 0.41, 0.37, 0.0, 1.37, 0.83, 1.1, 1},
                      ScatterCase{"tilted", 0.41, 0.37, 0.0, 1.37, 0.83, 1.1, 2},
                      ScatterCase{"random", 0.41, 0.37, 0.0, 1.37, 0.83, 1.1, 3},
                      ScatterCase{"random_sheared", 0.41, 0.37, 0.3, 1.37, 0.83, 1.1, 4},
                      ScatterCase{"simulated_probe_new_default_kernel", 98.0 / 255.0, 195.0 / 255.0, 0.0, 2.0, 1.0, 3.0, 2},
                      ScatterCase{"half_width_a_multiple_of_the_spacing", 0.5, 0.37, 0.0, 1.0, 0.83, 1.1, 5},
                      ScatterCase{"half_width_about_a_multiple", 0.4, 0.37, 0.0, 1.2, 0.83, 1.1, 6},
                      ScatterCase{"half_width_an_odd_multiple_of_half_the_spacing", 0.4, 0.37, 0.0, 1.0, 0.83, 1.1, 1},
                      // 3 * 0.37 + fmod(1.3, 0.37) rounds below 1.3: a kink that rounding moves inside.
                      ScatterCase{"kink_rounded_inwards", 0.37, 0.41, 0.0, 1.3, 0.83, 1.1, 0},
                      ScatterCase{"kink_rounded_inwards_tilted", 0.37, 0.41, 0.0, 1.3, 0.83, 1.1, 2}),
    [](const ::testing::TestParamInfo<ScatterCase>& i) { return std::string(i.param.name); });

// Reconstructing at R*P equals reconstructing at P with the voxel index
// rotated, for rotations that map the cubic grid onto itself. The kernel is
// asymmetric and the slice tilted, so a kernel fixed to the grid's axes fails.
TEST(TentKernel, RotatingPoseAndPatternTogetherGivesTheSameValues) {
  const std::int64_t n = 33, c = 16;  // voxel 16 sits on the rotation centre
  const Grid g = cubeGrid(n, 1.0);
  ReconSettings s = baseSettings();
  s.tent.kernelLateralMm = 1.6;
  s.tent.kernelAxialMm = 0.8;
  s.tent.kernelElevationMm = 1.5;
  const int w = 20, h = 16;
  const Frame f = makeFrame(w, h, [](int x, int y) { return 100.0 + 60.0 * std::sin(0.35 * x) * std::cos(0.25 * y); });
  const glm::dmat3 r0 = rot(Vec3(1, 0.4, -0.3), 0.6);
  const glm::dmat3 r1 = rot(Vec3(1, 0.4, -0.3), 0.66);
  const Mat4 p0 = centredPose(Vec3(0.31, -0.17, 0.23), r0, 0.9, 1.3, w, h);
  const Mat4 p1 = centredPose(Vec3(0.31, -0.17, 0.23) + r0[2] * 3.0, r1, 0.9, 1.3, w, h);

  auto reconstruct = [&](const Mat4& rw) {
    auto rec = makeTentReconstructor(g, s);
    rec->insert(f, rw * p0, 0.0);
    EXPECT_GT(rec->insert(f, rw * p1, 0.1).fillInSlices, 0);
    return rec;
  };
  auto ref = reconstruct(Mat4(1.0));
  const Volume refW = ref->weights();

  struct Rotation {
    const char* name;
    Mat4 m;
    std::function<Index3(Index3)> map;  // voxel of the reference -> voxel of the rotated
  };
  const std::vector<Rotation> rotations = {
      {"90 about z", rotationAxisAngle(Vec3(0, 0, 1), std::numbers::pi / 2), [&](Index3 v) { return Index3(2 * c - v.y, v.x, v.z); }},
      {"90 about x", rotationAxisAngle(Vec3(1, 0, 0), std::numbers::pi / 2), [&](Index3 v) { return Index3(v.x, 2 * c - v.z, v.y); }},
      {"-90 about y", rotationAxisAngle(Vec3(0, 1, 0), -std::numbers::pi / 2), [&](Index3 v) { return Index3(2 * c - v.z, v.y, v.x); }},
  };
  for (const Rotation& rt : rotations) {
    SCOPED_TRACE(rt.name);
    auto rec = reconstruct(rt.m);
    const Volume rw = rec->weights();
    std::size_t compared = 0;
    for (std::int64_t k = 0; k < n; ++k)
      for (std::int64_t j = 0; j < n; ++j)
        for (std::int64_t i = 0; i < n; ++i) {
          const Index3 q = rt.map(Index3(i, j, k));
          const std::size_t a = g.linear(i, j, k), b = g.linear(q.x, q.y, q.z);
          const float wa = f32(refW, a), wb = f32(rw, b);
          ASSERT_NEAR(wa, wb, 1e-5 * std::max(1.0f, wa)) << i << " " << j << " " << k;
          if (wa > 1e-4f) {
            ++compared;
            ASSERT_NEAR(f32(ref->output(), a), f32(rec->output(), b), 1e-3) << i << " " << j << " " << k;
          }
        }
    EXPECT_GT(compared, 1000u);
  }
}

// --------------------------------------------------------------- fill-in --

TEST(TentFillIn, SliceCountFollowsTheElevationHalfWidth) {
  const Grid g = cubeGrid(16, 1.0);
  const Frame f = constantFrame(4, 4, 100);
  auto count = [&](double he, double stepMm) {
    ReconSettings s = baseSettings();
    s.tent.kernelElevationMm = he;
    auto rec = makeTentReconstructor(g, s);
    rec->insert(f, imagePose(Vec3(0.0), glm::dmat3(1.0), 1.0, 1.0), 0.0);
    return rec->insert(f, imagePose(Vec3(0, 0, stepMm), glm::dmat3(1.0), 1.0, 1.0), 0.1).fillInSlices;
  };
  EXPECT_EQ(count(1.5, 2.0), 1);  // the pinned kernel, frames 2 mm apart
  EXPECT_EQ(count(0.5, 2.0), 3);  // the paper's 3 points between slices 2 mm apart
  EXPECT_EQ(count(1.5, 1.5), 0);  // within reach: no fill-in
  EXPECT_EQ(count(1.5, 1.6), 1);
  EXPECT_EQ(count(1.0, 5.0), 4);
}

// Every voxel inside the swept region must be covered with fill-in; without
// it there are holes (so the check can fail).
void expectNoHolesWithFillIn(const Grid& g, const std::vector<Mat4>& poses, const Frame& f, int expectFillIn,
                             const std::function<bool(const Vec3&)>& inside) {
  for (const bool fill : {true, false}) {
    ReconSettings s = baseSettings();
    s.tent.fillIn = fill;
    auto rec = makeTentReconstructor(g, s);
    for (std::size_t i = 0; i < poses.size(); ++i) {
      const InsertResult r = rec->insert(f, poses[i], 0.1 * static_cast<double>(i));
      EXPECT_EQ(r.fillInSlices, fill && i > 0 ? expectFillIn : 0) << "frame " << i;
    }
    std::size_t interior = 0, holes = 0;
    for (std::int64_t k = 0; k < g.dims.z; ++k)
      for (std::int64_t j = 0; j < g.dims.y; ++j)
        for (std::int64_t i = 0; i < g.dims.x; ++i) {
          if (!inside(voxelCentre(g, i, j, k))) continue;
          ++interior;
          holes += rec->covered(g.linear(i, j, k)) ? 0 : 1;
        }
    EXPECT_GT(interior, 2000u);
    if (fill)
      EXPECT_EQ(holes, 0u) << "of " << interior << " voxels inside the sweep";
    else
      EXPECT_GT(holes, interior / 10) << "without fill-in there should be holes";
  }
}

TEST(TentFillIn, NoHolesInATiltedSweepWithFiveMillimetreSteps) {
  const Grid g = cubeGrid(48, 1.0);
  const int w = 24, h = 24;
  const Frame f = constantFrame(w, h, 90);
  const glm::dmat3 r = rot(Vec3(1, 1, 0), 0.5);
  const Vec3 o = Vec3(0.0) - r[0] * 11.5 - r[1] * 11.5 - r[2] * 10.0;
  std::vector<Mat4> poses;
  for (int i = 0; i < 5; ++i) poses.push_back(imagePose(o + r[2] * (5.0 * i), r, 1.0, 1.0));
  // ceil(5 / 1.5) - 1 = 3 intermediate slices per gap.
  expectNoHolesWithFillIn(g, poses, f, 3, [&](const Vec3& x) {
    const Vec3 d = x - o;
    const double u = glm::dot(d, r[0]), v = glm::dot(d, r[1]), nn = glm::dot(d, r[2]);
    return u >= 1.0 && u <= 22.0 && v >= 1.0 && v <= 22.0 && nn >= 0.0 && nn <= 20.0;
  });
}

TEST(TentFillIn, NoHolesInAFanSweep) {
  // The probe rocks about its face (the image's top edge), 10 degrees a frame.
  const Grid g = cubeGrid(48, 1.0);
  const int w = 24, h = 30;
  const Frame f = constantFrame(w, h, 90);
  const Vec3 o(-11.5, -14.0, -8.0);
  std::vector<Mat4> poses;
  for (int i = 0; i < 4; ++i) poses.push_back(imagePose(o, rot(Vec3(1, 0, 0), glm::radians(10.0 * i)), 1.0, 1.0));
  // Bottom corners move 2 * 29 * sin(5 deg) = 5.06 mm: ceil(5.06 / 1.5) - 1 = 3.
  expectNoHolesWithFillIn(g, poses, f, 3, [&](const Vec3& x) {
    const Vec3 d = x - o;
    const double rho = std::hypot(d.y, d.z), phi = std::atan2(d.z, d.y) * 180.0 / std::numbers::pi;
    return d.x >= 1.0 && d.x <= 22.0 && rho >= 1.0 && rho <= 28.0 && phi >= 0.0 && phi <= 30.0;
  });
}

// Rejected pixels differ from frame to frame (here a dark corner, then a
// dark edge): fill-in still happens, over the pixels kept in both frames.
TEST(TentFillIn, BridgesFramesWhoseRejectedPixelsDiffer) {
  const Grid g = cubeGrid(32, 1.0);
  ReconSettings s = baseSettings();
  s.pixelRejectionThreshold = 10;
  auto rec = makeTentReconstructor(g, s);
  const Frame a = makeFrame(12, 12, [](int x, int y) { return x == 0 && y == 0 ? 0.0 : 100.0; });
  const Frame b = makeFrame(12, 12, [](int x, int) { return x == 11 ? 0.0 : 100.0; });
  const Vec3 o(-5.5, -5.5, -2.5);
  EXPECT_EQ(rec->insert(a, imagePose(o, glm::dmat3(1.0), 1.0, 1.0), 0.0).pixelsInserted, 143u);
  const InsertResult r = rec->insert(b, imagePose(o + Vec3(0, 0, 5), glm::dmat3(1.0), 1.0, 1.0), 0.1);
  EXPECT_EQ(r.pixelsInserted, 132u);
  EXPECT_EQ(r.fillInSlices, 3);
  // Midway between the frames, under pixels kept in both.
  const Index3 v(glm::round(g.worldToVoxel(o + Vec3(5.0, 5.0, 2.5))));
  EXPECT_TRUE(rec->covered(g.linear(v.x, v.y, v.z)));
  EXPECT_NEAR(f32(rec->output(), g.linear(v.x, v.y, v.z)), 100.0, 1e-3);
}

TEST(TentFillIn, NotAcrossAJumpOrALargeRotation) {
  const Grid g = cubeGrid(48, 1.0);
  const int w = 20, h = 20;
  const Frame f = constantFrame(w, h, 90);
  const std::size_t mid = g.linear(24, 24, 24);  // (0.5, 0.5, 0.5) mm
  // Translation by 20 mm, more than fill_in_max_gap_mm = 12.
  for (const double maxGap : {12.0, 25.0}) {
    ReconSettings s = baseSettings();
    s.tent.fillInMaxGapMm = maxGap;
    auto rec = makeTentReconstructor(g, s);
    const Vec3 o(-9.5, -9.5, -9.5);
    rec->insert(f, imagePose(o, glm::dmat3(1.0), 1.0, 1.0), 0.0);
    const InsertResult r = rec->insert(f, imagePose(o + Vec3(0, 0, 20), glm::dmat3(1.0), 1.0, 1.0), 0.1);
    if (maxGap < 20.0) {
      EXPECT_EQ(r.fillInSlices, 0);
      EXPECT_FALSE(rec->covered(mid));
    } else {
      EXPECT_EQ(r.fillInSlices, 13);  // ceil(20 / 1.5) - 1
      EXPECT_TRUE(rec->covered(mid));
    }
  }
  // Rotation by 30 degrees about the top edge, more than fill_in_max_angle_deg = 20.
  for (const double maxAngle : {20.0, 40.0}) {
    ReconSettings s = baseSettings();
    s.tent.fillInMaxAngleDeg = maxAngle;
    s.tent.fillInMaxGapMm = 100.0;
    auto rec = makeTentReconstructor(g, s);
    const Vec3 o(-9.5, -20.0, -5.0);
    rec->insert(f, imagePose(o, glm::dmat3(1.0), 1.0, 1.0), 0.0);
    const InsertResult r = rec->insert(f, imagePose(o, rot(Vec3(1, 0, 0), glm::radians(30.0)), 1.0, 1.0), 0.1);
    // A voxel at 15 degrees, 17 mm from the axis: 4.4 mm from both frames.
    const Vec3 x = o + Vec3(10.0, 17.0 * std::cos(glm::radians(15.0)), 17.0 * std::sin(glm::radians(15.0)));
    const Index3 v(glm::round(g.worldToVoxel(x)));
    const bool cov = rec->covered(g.linear(v.x, v.y, v.z));
    if (maxAngle < 30.0) {
      EXPECT_EQ(r.fillInSlices, 0);
      EXPECT_FALSE(cov);
    } else {
      EXPECT_GT(r.fillInSlices, 0);
      EXPECT_TRUE(cov);
    }
  }
}

// ----------------------------------------------------------- replacement --

// A 20 x 20 mm image swept along z over [-10, 10] in 2 mm steps.
struct Sweep {
  Grid grid = cubeGrid(40, 1.0);
  int w = 20, h = 20;
  Mat4 at(double z) const { return imagePose(Vec3(-9.5, -9.5, z), glm::dmat3(1.0), 1.0, 1.0); }
  // Far from the rectangle's edges and from the turnarounds.
  bool interior(std::int64_t i, std::int64_t j, std::int64_t k) const {
    const Vec3 x = voxelCentre(grid, i, j, k);
    return std::abs(x.x) < 8.0 && std::abs(x.y) < 8.0 && std::abs(x.z) < 6.0;
  }
  template <typename F>
  void forInterior(F&& fn) const {
    for (std::int64_t k = 0; k < grid.dims.z; ++k)
      for (std::int64_t j = 0; j < grid.dims.y; ++j)
        for (std::int64_t i = 0; i < grid.dims.x; ++i)
          if (interior(i, j, k)) fn(grid.linear(i, j, k));
  }
};

// Forward with A, then back with B (as if the tissue had changed).
std::unique_ptr<Reconstructor> forwardThenBack(const Sweep& sw, const ReconSettings& s, double a, double b,
                                               bool backwards) {
  auto rec = makeTentReconstructor(sw.grid, s);
  const Frame fa = constantFrame(sw.w, sw.h, a), fb = constantFrame(sw.w, sw.h, b);
  double t = 0.0;
  for (int z = -10; z <= 10; z += 2, t += 0.1) rec->insert(fa, sw.at(z), t);
  if (backwards) {
    for (int z = 10; z >= -10; z -= 2, t += 0.1) rec->insert(fb, sw.at(z), t);
  } else {  // jump back to the start and sweep forward again
    for (int z = -10; z <= 10; z += 2, t += 0.1) rec->insert(fb, sw.at(z), t);
  }
  return rec;
}

TEST(TentReplacement, MotionVectorsLetTheReverseSweepDominate) {
  const Sweep sw;
  ReconSettings acc = baseSettings();
  ReconSettings mv = baseSettings();
  mv.tent.replacement = pp5::gp::Replacement::MotionVector;
  mv.tent.motionVectorNewWeight = 0.8;
  const double a = 50.0, b = 200.0;
  auto ra = forwardThenBack(sw, acc, a, b, true);
  auto rm = forwardThenBack(sw, mv, a, b, true);
  std::size_t n = 0;
  sw.forInterior([&](std::size_t i) {
    ++n;
    // Both sweeps put the same weight everywhere: the plain mean is halfway.
    ASSERT_NEAR(f32(ra->output(), i), 0.5 * (a + b), 0.01);
    // The old sweep keeps a share of 1 - 0.8.
    ASSERT_NEAR(f32(rm->output(), i), 0.2 * a + 0.8 * b, 0.01);
  });
  EXPECT_GT(n, 3000u);
}

TEST(TentReplacement, SameDirectionRescanAccumulatesEvenWithMotionVectors) {
  const Sweep sw;
  ReconSettings acc = baseSettings();
  ReconSettings mv = baseSettings();
  mv.tent.replacement = pp5::gp::Replacement::MotionVector;
  auto ra = forwardThenBack(sw, acc, 50.0, 200.0, false);
  auto rm = forwardThenBack(sw, mv, 50.0, 200.0, false);
  EXPECT_EQ(ra->output().bytes, rm->output().bytes);
  EXPECT_EQ(ra->weights().bytes, rm->weights().bytes);
  sw.forInterior([&](std::size_t i) { ASSERT_NEAR(f32(rm->output(), i), 125.0, 0.01); });
}

TEST(TentReplacement, DecayFadesOldDataWhenNewDataArrives) {
  const Sweep sw;
  ReconSettings s = baseSettings();
  s.tent.replacement = pp5::gp::Replacement::Decay;
  s.tent.decayTauS = 2.0;
  const double a = 50.0, b = 200.0;
  const Frame fa = constantFrame(sw.w, sw.h, a), fb = constantFrame(sw.w, sw.h, b);
  const Frame far = constantFrame(4, 4, 10.0);

  auto once = makeTentReconstructor(sw.grid, baseSettings());
  once->insert(fa, sw.at(0.25), 0.0);
  const Volume w1 = once->weights();

  auto rec = makeTentReconstructor(sw.grid, s);
  rec->insert(fa, sw.at(0.25), 0.0);
  // Time passes, data lands elsewhere: the first slice's voxels keep their weight.
  rec->insert(far, imagePose(Vec3(-15, -15, -15), glm::dmat3(1.0), 1.0, 1.0), 3.0);
  const Volume wMid = rec->weights();
  // The same place again, 3 tau after the first frame.
  rec->insert(fb, sw.at(0.25), 6.0);
  const Volume w2 = rec->weights();
  const double e3 = std::exp(-3.0);
  std::size_t checked = 0;
  for (std::size_t i = 0; i < sw.grid.voxelCount(); ++i) {
    const double w = f32(w1, i);
    if (w < 1e-3) continue;
    ++checked;
    ASSERT_EQ(f32(wMid, i), f32(w1, i));
    ASSERT_NEAR(f32(w2, i), w * (1.0 + e3), 1e-5 * w);
    ASSERT_NEAR(f32(rec->output(), i), (a * e3 + b) / (e3 + 1.0), 1e-3);
  }
  EXPECT_GT(checked, 1000u);
}

// A timestamp that repeats or goes back (a recording's clock stepped) never
// raises an older voxel's weight: the decay counts only forward, so the
// voxels end as plain accumulation would leave them.
TEST(TentReplacement, DecayNeverCountsBackwards) {
  const Sweep sw;
  ReconSettings s = baseSettings();
  s.tent.replacement = pp5::gp::Replacement::Decay;
  s.tent.decayTauS = 2.0;
  const Frame fa = constantFrame(sw.w, sw.h, 50.0), fb = constantFrame(sw.w, sw.h, 200.0);
  auto plain = makeTentReconstructor(sw.grid, baseSettings());
  plain->insert(fa, sw.at(0.25), 10.0);
  plain->insert(fb, sw.at(0.25), 10.0);
  for (const double tb : {10.0, 4.0}) {  // repeats, goes back
    // The log, to see that it is said (once).
    std::ostringstream said;
    const auto before = spdlog::default_logger();
    spdlog::set_default_logger(
        std::make_shared<spdlog::logger>("test", std::make_shared<spdlog::sinks::ostream_sink_mt>(said)));
    auto rec = makeTentReconstructor(sw.grid, s);
    rec->insert(fa, sw.at(0.25), 10.0);
    rec->insert(fb, sw.at(0.25), tb);
    rec->insert(fb, sw.at(0.25), tb - 1.0);
    spdlog::set_default_logger(before);
    EXPECT_EQ(rec->weights().bytes.size(), plain->weights().bytes.size());
    const std::string text = said.str();
    const auto first = text.find("does not come after the previous frame's");
    EXPECT_NE(first, std::string::npos) << text;
    EXPECT_EQ(text.find("does not come after", first + 1), std::string::npos) << text;  // once
    // Two frames only: the voxels as plain accumulation leaves them.
    auto two = makeTentReconstructor(sw.grid, s);
    two->insert(fa, sw.at(0.25), 10.0);
    two->insert(fb, sw.at(0.25), tb);
    EXPECT_EQ(two->output().bytes, plain->output().bytes) << tb;
    EXPECT_EQ(two->weights().bytes, plain->weights().bytes) << tb;
  }
}

TEST(TentReplacement, DecayedSweepRescanIsDominatedByTheNewSweep) {
  const Sweep sw;
  ReconSettings s = baseSettings();
  s.tent.replacement = pp5::gp::Replacement::Decay;
  s.tent.decayTauS = 0.5;
  auto rec = makeTentReconstructor(sw.grid, s);
  const Frame fa = constantFrame(sw.w, sw.h, 50), fb = constantFrame(sw.w, sw.h, 200);
  // Each sweep takes 1.1 s; the rescan starts 3 tau after the first ends.
  for (int i = 0; i <= 10; ++i) rec->insert(fa, sw.at(-10 + 2 * i), 0.1 * i);
  for (int i = 0; i <= 10; ++i) rec->insert(fb, sw.at(-10 + 2 * i), 2.5 + 0.1 * i);
  sw.forInterior([&](std::size_t i) {
    const float v = f32(rec->output(), i);
    ASSERT_GT(v, 50.0 + 0.95 * 150.0);
    ASSERT_LT(v, 200.0);
  });
}

// ------------------------------------------ incremental and deterministic --

struct Shot {
  Frame frame;
  Mat4 pose;
  double t;
};

// A tilted sweep forward, back, a jump and forward again: fill-in, rebases
// and decay all happen. Pixels about the pinned kernel's size (8 x 2 window).
std::vector<Shot> mixedSequence() {
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> dist(0, 255);
  std::vector<Shot> shots;
  const int w = 40, h = 24;
  auto frame = [&]() {
    std::vector<int> v(static_cast<std::size_t>(w * h));
    for (int& x : v) x = dist(rng);
    return makeFrame(w, h, [v, w](int x, int y) { return v[static_cast<std::size_t>(y * w + x)]; });
  };
  const Vec3 axis(0.2, 1, 0.3);
  double t = 0.0;
  auto add = [&](double n, double angle) {
    const glm::dmat3 r = rot(axis, angle);
    shots.push_back({frame(), centredPose(r[2] * n + Vec3(0.3, -0.2, 0.1), r, 0.4, 0.76, w, h), t});
    t += 0.4;
  };
  for (int i = 0; i < 5; ++i) add(-8.0 + 3.0 * i, 0.5 + 0.05 * i);  // forward, 3 mm steps
  for (int i = 0; i < 3; ++i) add(2.0 - 2.5 * i, 0.65 - 0.04 * i);   // back
  add(9.0, 0.2);                                                      // a jump
  for (int i = 1; i < 3; ++i) add(9.0 - 2.0 * i, 0.2 + 0.03 * i);
  return shots;
}

// Per voxel, the largest bound (RowRun::newMax) of the runs that hold it,
// NaN where none does (every run inside the grid).
std::vector<float> runBounds(const Grid& g, const std::vector<RowRun>& runs) {
  std::vector<float> m(g.voxelCount(), std::numeric_limits<float>::quiet_NaN());
  for (const RowRun& r : runs) {
    EXPECT_TRUE(r.j >= 0 && r.j < g.dims.y && r.k >= 0 && r.k < g.dims.z && r.i0 >= 0 && r.i0 <= r.i1 &&
                r.i1 < g.dims.x);
    for (std::int64_t i = r.i0; i <= r.i1; ++i) {
      float& b = m[g.linear(i, r.j, r.k)];
      b = std::isnan(b) ? r.newMax : std::max(b, r.newMax);
    }
  }
  return m;
}

// The dirty region covers every voxel whose output or weight changed, and the
// changed runs every voxel whose output bits changed, with a bound at least
// its new value.
TEST(TentDeterminism, IncrementalEqualsBatchForAnyThreadCountAndDirtyCoversEveryChange) {
  const Grid g = cubeGrid(40, 1.0);
  const std::vector<Shot> shots = mixedSequence();
  for (const char* mode : {"accumulate", "motion_vector", "decay"}) {
    SCOPED_TRACE(mode);
    ReconSettings s = baseSettings();
    s.tent.replacement = pp5::enumFromName<pp5::gp::Replacement>(mode);
    // Dark pixels left out, except for accumulate (whose voxels then take
    // the shortcut for windows with every pixel selected).
    s.pixelRejectionThreshold = std::string(mode) == "accumulate" ? -1.0 : 20.0;
    s.tent.decayTauS = 1.0;
    s.tent.motionVectorBrick = 4;

    // Batch, one thread, no reading in between.
    auto batch = makeTentReconstructor(g, s);
    int fillIns = 0;
    for (const Shot& sh : shots) fillIns += batch->insert(sh.frame, sh.pose, sh.t).fillInSlices;
    EXPECT_GT(fillIns, 4);
    const Volume batchW = batch->weights();

    for (const int threads : {1, 2, 3}) {
      SCOPED_TRACE(threads);
      s.threads = threads;
      auto rec = makeTentReconstructor(g, s);
      Volume prevOut = rec->output(), prevW = rec->weights();
      for (std::size_t n = 0; n < shots.size(); ++n) {
        const InsertResult r = rec->insert(shots[n].frame, shots[n].pose, shots[n].t);
        const Volume w = rec->weights();
        ASSERT_TRUE(rec->reportsChangedRuns());
        const std::vector<float> inRuns = runBounds(g, r.changedRuns);
        std::size_t changed = 0, outputChanged = 0;
        for (std::int64_t k = 0; k < g.dims.z; ++k)
          for (std::int64_t j = 0; j < g.dims.y; ++j)
            for (std::int64_t i = 0; i < g.dims.x; ++i) {
              const std::size_t li = g.linear(i, j, k);
              const bool diff = std::memcmp(prevOut.bytes.data() + 4 * li, rec->output().bytes.data() + 4 * li, 4) != 0 ||
                                std::memcmp(prevW.bytes.data() + 4 * li, w.bytes.data() + 4 * li, 4) != 0;
              if (!diff) continue;
              ++changed;
              ASSERT_TRUE(r.dirty.containsVoxel(i, j, k)) << "frame " << n << " changed voxel " << i << " " << j
                                                          << " " << k << " outside its dirty region";
              if (std::memcmp(prevOut.bytes.data() + 4 * li, rec->output().bytes.data() + 4 * li, 4) == 0) continue;
              ++outputChanged;
              ASSERT_FALSE(std::isnan(inRuns[li])) << "frame " << n << " changed output at " << i << " " << j << " "
                                                   << k << " outside the changed runs";
              float now;
              std::memcpy(&now, rec->output().bytes.data() + 4 * li, 4);
              ASSERT_LE(now, inRuns[li]) << "frame " << n << " voxel " << i << " " << j << " " << k
                                         << ": its run's bound is below its new value";
            }
        EXPECT_GT(changed, 100u) << "frame " << n;
        EXPECT_GT(outputChanged, 100u) << "frame " << n;
        EXPECT_LT(r.dirty.voxelCount(), g.voxelCount()) << "frame " << n;
        prevOut = rec->output();
        prevW = w;
      }
      EXPECT_EQ(rec->output().bytes, batch->output().bytes);
      EXPECT_EQ(prevW.bytes, batchW.bytes);
    }
  }
}

// On a fine grid the 16-voxel bricks are small next to the kernel's reach,
// so a dirty region that reached less far than the kernel would miss bricks.
TEST(TentDeterminism, DirtyRegionCoversEveryChangeForRandomPoses) {
  const Grid g = cubeGrid(64, 0.25);
  ReconSettings s = baseSettings();
  s.tent.kernelLateralMm = 0.9;
  s.tent.kernelAxialMm = 0.6;
  s.tent.kernelElevationMm = 1.2;
  auto rec = makeTentReconstructor(g, s);
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  const Frame f = makeFrame(16, 12, [](int x, int y) { return 30.0 + 7.0 * x + 5.0 * y; });
  Volume prevW = rec->weights();
  std::size_t changedTotal = 0;
  for (int n = 0; n < 30; ++n) {
    const glm::dmat3 r = rot(Vec3(uni(rng), uni(rng), uni(rng)) + Vec3(0.0, 0.0, 1e-3), 3.0 * uni(rng));
    const Vec3 centre(3.0 * uni(rng), 3.0 * uni(rng), 3.0 * uni(rng));
    const InsertResult res = rec->insert(f, centredPose(centre, r, 0.3, 0.3, 16, 12), 0.1 * n);
    const Volume w = rec->weights();
    for (std::int64_t k = 0; k < g.dims.z; ++k)
      for (std::int64_t j = 0; j < g.dims.y; ++j)
        for (std::int64_t i = 0; i < g.dims.x; ++i) {
          const std::size_t li = g.linear(i, j, k);
          if (std::memcmp(prevW.bytes.data() + 4 * li, w.bytes.data() + 4 * li, 4) == 0) continue;
          ++changedTotal;
          ASSERT_TRUE(res.dirty.containsVoxel(i, j, k)) << "insert " << n << " voxel " << i << " " << j << " " << k;
        }
    prevW = w;
  }
  EXPECT_GT(changedTotal, 10000u);
}

TEST(TentDeterminism, ATiltedSliceDirtiesAThinSlab) {
  const Grid g = cubeGrid(128, 1.0);
  auto rec = makeTentReconstructor(g, baseSettings());
  const int w = 100, h = 100;
  const Frame f = constantFrame(w, h, 120);
  const InsertResult r =
      rec->insert(f, centredPose(Vec3(0.3, 0.2, 0.1), rot(Vec3(1, 0, 0), glm::radians(30.0)), 0.8, 0.8, w, h), 0.0);
  const double frac = static_cast<double>(r.dirty.voxelCount()) / static_cast<double>(g.voxelCount());
  EXPECT_LT(frac, 0.15);
  RecordProperty("dirty_fraction", std::to_string(frac));
  // The slice's axis-aligned bounding box would be several times larger.
  const Box3 bb = r.dirty.bounds();
  EXPECT_LT(static_cast<double>(r.dirty.voxelCount()), 0.5 * static_cast<double>(bb.voxelCount()));
  std::size_t covered = 0;
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j)
      for (std::int64_t i = 0; i < g.dims.x; ++i)
        if (rec->covered(g.linear(i, j, k))) {
          ++covered;
          ASSERT_TRUE(r.dirty.containsVoxel(i, j, k));
        }
  EXPECT_GT(covered, 15000u);
}

// ------------------------------------------------------------ bad input --

TEST(TentInput, RefusesBadFramesAndPosesWithoutChangingAnything) {
  const Grid g = cubeGrid(16, 1.0);
  auto rec = makeTentReconstructor(g, baseSettings());
  const Frame good = constantFrame(4, 4, 80);
  const Mat4 pose = imagePose(Vec3(-1.5, -1.5, 0.2), glm::dmat3(1.0), 1.0, 1.0);

  Mat4 nan = pose;
  nan[3][1] = std::nan("");
  EXPECT_THROW(rec->insert(good, nan, 0.0), InputError);
  Mat4 inf = pose;
  inf[0][0] = std::numeric_limits<double>::infinity();
  EXPECT_THROW(rec->insert(good, inf, 0.0), InputError);
  Mat4 flat = pose;
  flat[1] = flat[0];  // both pixel axes the same: the image is a line
  EXPECT_THROW(rec->insert(good, flat, 0.0), InputError);
  Mat4 projective = pose;
  projective[0][3] = 0.5;
  EXPECT_THROW(rec->insert(good, projective, 0.0), InputError);
  Frame empty;
  EXPECT_THROW(rec->insert(empty, pose, 0.0), InputError);
  Frame shortBuffer = good;
  shortBuffer.pixels.resize(5);
  EXPECT_THROW(rec->insert(shortBuffer, pose, 0.0), InputError);
  EXPECT_THROW(rec->insert(good, pose, std::nan("")), InputError);
  EXPECT_THROW(rec->insert(good, pose, -1e308), InputError);  // a damaged field, not a time
  EXPECT_THROW(rec->advance(4, 4, pose, 2e10), InputError);
  // Pixels a micrometre wide: the kernel would span thousands of them.
  EXPECT_THROW(rec->insert(good, imagePose(Vec3(0.0), glm::dmat3(1.0), 1e-3, 1.0), 0.0), InputError);
  for (std::size_t i = 0; i < g.voxelCount(); ++i) ASSERT_FALSE(rec->covered(i));

  // Still usable, and the same as a fresh one.
  rec->insert(good, pose, 0.0);
  auto fresh = makeTentReconstructor(g, baseSettings());
  fresh->insert(good, pose, 0.0);
  EXPECT_EQ(rec->output().bytes, fresh->output().bytes);

  ReconSettings bad = baseSettings();
  bad.tent.replacement = static_cast<Replacement>(7);  // not a policy: settings built in code are checked
  EXPECT_THROW(makeTentReconstructor(g, bad), InputError);
}

TEST(TentInput, BytesPerVoxel) {
  ReconSettings s;
  EXPECT_EQ(tentBytesPerVoxel(s), 12u);
  s.tent.replacement = pp5::gp::Replacement::Decay;
  EXPECT_EQ(tentBytesPerVoxel(s), 16u);
  s.tent.replacement = pp5::gp::Replacement::MotionVector;
  s.tent.motionVectorBrick = 8;
  EXPECT_EQ(tentBytesPerVoxel(s), 21u);
}

}  // namespace
}  // namespace pp5::gp

// ------------------------------------------------------------ simulator --

namespace pp5::gp {
namespace {

double correlation(const std::vector<double>& x, const std::vector<double>& y) {
  const double n = static_cast<double>(x.size());
  double sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    sx += x[i];
    sy += y[i];
    sxx += x[i] * x[i];
    syy += y[i] * y[i];
    sxy += x[i] * y[i];
  }
  return (sxy - sx * sy / n) / std::sqrt((sxx - sx * sx / n) * (syy - sy * sy / n));
}

// A whole simulated doll sweep (small frames, so it stays cheap) through the
// simulator's own poses and timestamps. Each pixel is also dropped into its
// nearest voxel through transformPoint, independently of the tent code: the
// two must agree closely (the image-to-reference convention holds end to
// end), and both follow the truth volume. Speckle, shadows and the coarse
// pixels keep any reconstruction of these frames far from the truth, so that
// check only asks for a clear positive correlation.
TEST(TentSimulated, DollSweepAgreesWithNearestVoxelAndFollowsTheTruth) {
  sim::SimSettings ss;
  ss.phantom = pp5::sim::PhantomKind::Doll;
  ss.threads = 2;
  ss.probe.widthPx = 48;
  ss.probe.heightPx = 72;
  ss.sweep.captureIntervalMm = 6.0;  // fewer frames; fill-in bridges the gaps
  const sim::SweepSimulator simulator(ss);
  std::vector<Frame> frames;
  simulator.run(2, [&](Frame&& f) { frames.push_back(std::move(f)); });
  const std::size_t n = frames.size();
  ASSERT_GT(n, 10u);
  std::vector<Mat4> poses;
  for (std::size_t i = 0; i < n; ++i) poses.push_back(simulator.imageToReference(i));
  const Grid g = sim::fitGrid(poses, simulator.probe().width, simulator.probe().height, Vec3(2.0), 2.0);

  ReconSettings s = baseSettings();
  s.threads = 2;
  s.tent.replacement = pp5::gp::Replacement::MotionVector;
  s.tent.kernelLateralMm = 2.0;  // this small probe's pixels are about 2 x 2.7 mm
  s.tent.kernelAxialMm = 2.0;
  auto rec = makeTentReconstructor(g, s);
  int fillIns = 0;
  for (std::size_t i = 0; i < n; ++i) fillIns += rec->insert(frames[i], poses[i], frames[i].timestamp).fillInSlices;
  EXPECT_GT(fillIns, static_cast<int>(n));

  std::vector<double> sum(g.voxelCount(), 0.0), count(g.voxelCount(), 0.0);
  for (std::size_t q = 0; q < n; ++q)
    for (int r = 0; r < frames[q].height; ++r)
      for (int c = 0; c < frames[q].width; ++c) {
        const Index3 iv(glm::round(g.worldToVoxel(transformPoint(poses[q], Vec3(c, r, 0)))));
        if (!g.contains(iv.x, iv.y, iv.z)) continue;
        const std::size_t li = g.linear(iv.x, iv.y, iv.z);
        sum[li] += frames[q].value(c, r);
        count[li] += 1.0;
      }
  const Volume truth = sim::truthVolume(simulator.phantom(), simulator.bmode(), g, ScalarType::F32, 2);
  std::vector<double> tent, nearest, tru;
  std::size_t coveredOnlyByTent = 0;
  for (std::size_t v = 0; v < g.voxelCount(); ++v) {
    if (!rec->covered(v)) {
      ASSERT_EQ(count[v], 0.0) << "voxel " << v << " got a pixel but no tent weight";
      continue;
    }
    if (count[v] == 0.0) {
      ++coveredOnlyByTent;
      continue;
    }
    tent.push_back(f32(rec->output(), v));
    nearest.push_back(sum[v] / count[v]);
    tru.push_back(truth.value(v));
  }
  ASSERT_GT(tent.size(), g.voxelCount() / 5);
  EXPECT_GT(coveredOnlyByTent, g.voxelCount() / 20);  // fill-in bridges the 6 mm between frames
  const double agree = correlation(tent, nearest), follow = correlation(tent, tru);
  RecordProperty("correlation_nearest", std::to_string(agree));
  RecordProperty("correlation_truth", std::to_string(follow));
  EXPECT_GT(agree, 0.9);
  EXPECT_GT(follow, 0.15);
}

}  // namespace
}  // namespace pp5::gp
