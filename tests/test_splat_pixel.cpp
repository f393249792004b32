// PLUS-compatible pixel reconstruction (nearest neighbour, trilinear): pixel
// selection, weights, compounding in both arithmetics, thread-count
// invariance, incremental output and dirty regions, bad input.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "core/error.hpp"
#include "reconstruction/fan_mask.hpp"
#include "reconstruction/fixed_point.hpp"
#include "reconstruction/reconstruction.hpp"
#include "reconstruction/splat_pixel.hpp"

namespace {

using namespace pp5;
using namespace pp5::gp;

float at(const Volume& v, std::size_t i) {
  float f;
  std::memcpy(&f, v.bytes.data() + 4 * i, 4);
  return f;
}

Frame makeFrame(int w, int h, const std::function<int(int, int)>& value, PixelType type = PixelType::U8) {
  Frame f;
  f.allocate(w, h, type);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const int v = value(x, y);
      const std::size_t i = static_cast<std::size_t>(y) * w + x;
      if (type == PixelType::U8) {
        f.pixels[i] = static_cast<std::uint8_t>(v);
      } else {
        f.pixels[2 * i] = static_cast<std::uint8_t>(v & 0xff);
        f.pixels[2 * i + 1] = static_cast<std::uint8_t>(v >> 8);
      }
    }
  return f;
}

Grid makeGrid(Index3 dims, double spacing, Vec3 origin = Vec3(0.0)) {
  Grid g;
  g.dims = dims;
  g.spacing = Vec3(spacing);
  g.origin = origin;
  return g;
}

// Image axes ex, ey (unit), pixel size, and the world position of pixel (0, 0).
Mat4 imagePose(const Vec3& ex, const Vec3& ey, double pixelMm, const Vec3& origin) {
  Mat4 m(1.0);
  m[0] = Vec4(ex * pixelMm, 0.0);
  m[1] = Vec4(ey * pixelMm, 0.0);
  m[2] = Vec4(glm::normalize(glm::cross(ex, ey)), 0.0);
  m[3] = Vec4(origin, 1.0);
  return m;
}

// A random rigid pose of a w x h image centred near `centre` (mm).
Mat4 randomPose(std::mt19937& rng, int w, int h, double pixelMm, const Vec3& centre, double jitterMm) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Vec3 axis = glm::normalize(Vec3(u(rng), u(rng), u(rng)) + Vec3(1e-3));
  const Mat4 r = rotationAxisAngle(axis, u(rng) * 3.14159);
  const Vec3 ex = transformVector(r, Vec3(1, 0, 0)), ey = transformVector(r, Vec3(0, 1, 0));
  const Vec3 c = centre + Vec3(u(rng), u(rng), u(rng)) * jitterMm;
  return imagePose(ex, ey, pixelMm, c - ex * (pixelMm * (w - 1) / 2.0) - ey * (pixelMm * (h - 1) / 2.0));
}

ReconSettings settingsFor(const std::string& arithmetic, const std::string& method, const std::string& compounding,
                          int threads = 1) {
  ReconSettings s;
  s.arithmetic = pp5::enumFromName<pp5::gp::Arithmetic>(arithmetic);
  s.method = pp5::enumFromName<pp5::gp::Method>(method);
  s.pixel.compounding = pp5::enumFromName<pp5::gp::Compounding>(compounding);
  s.threads = threads;
  return s;
}

struct Combo {
  const char* arithmetic;
  const char* method;
  const char* compounding;
};
std::vector<Combo> allCombos() {
  std::vector<Combo> c;
  for (const char* a : {"float", "plus"})
    for (const char* m : {"nearest", "trilinear"})
      for (const char* k : {"mean", "latest", "maximum"}) c.push_back({a, m, k});
  return c;
}
std::string name(const Combo& c) { return std::string(c.arithmetic) + "/" + c.method + "/" + c.compounding; }

std::vector<Frame> randomFrames(std::mt19937& rng, int count, int w, int h) {
  std::uniform_int_distribution<int> px(0, 255);
  std::vector<Frame> frames;
  for (int k = 0; k < count; ++k) frames.push_back(makeFrame(w, h, [&](int, int) { return px(rng); }));
  return frames;
}

// ---------------------------------------------------------------------------
// Pixel selection

TEST(PixelRuns, ClipRectangleIncludesItsEndAsPlusDoes) {
  ReconSettings s;
  s.clipOrigin = {5, 2};
  s.clipSize = {6, 3};
  const auto runs = pixelRuns(20, 10, s);
  ASSERT_EQ(runs.size(), 4u);  // rows 2..5
  for (std::size_t k = 0; k < runs.size(); ++k) EXPECT_EQ(runs[k], (PixelRun{int(2 + k), 5, 11}));
  // Clipped to the frame, and no clip at all.
  s.clipOrigin = {15, 8};
  EXPECT_EQ(pixelRuns(20, 10, s).back(), (PixelRun{9, 15, 19}));
  EXPECT_EQ(pixelRuns(20, 10, ReconSettings{}).size(), 10u);
  // A rectangle wholly outside the frames (made for the uncropped recording)
  // is refused, not an empty volume without a word.
  s.clipOrigin = {192, 16};
  s.clipSize = {420, 580};
  try {
    (void)pixelRuns(20, 10, s);
    ADD_FAILURE() << "no error for a clip rectangle outside the frames";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("lies outside the 20x10 frames"), std::string::npos) << e.what();
  }
}

TEST(PixelRuns, FanOfTheTrusConfigs) {
  ReconSettings s;
  s.clipOrigin = {192, 16};
  s.clipSize = {420, 580};
  s.fanAnglesDeg = {-45, 45};
  s.fanOriginPx = {380, 20};
  s.fanRadiusStartPx = 120;
  s.fanRadiusStopPx = 360;
  const auto runs = pixelRuns(820, 616, s);
  ASSERT_FALSE(runs.empty());
  std::vector<std::vector<bool>> in(616, std::vector<bool>(820, false));
  for (const auto& r : runs)
    for (int x = r.x0; x <= r.x1; ++x) in[r.y][x] = true;
  for (int y = 0; y < 616; ++y)
    for (int x = 0; x < 820; ++x) {
      const double dx = x - 380.0, dy = y - 20.0, r2 = dx * dx + dy * dy;
      const bool clip = x >= 192 && x <= 612 && y >= 16 && y <= 596;
      // PLUS keeps each edge one pixel inside the fan, except the inner
      // radius, whose cut-out keeps a pixel's margin inside the circle.
      const bool maybe = clip && dy > 0 && std::abs(dx) <= dy && r2 < 360.0 * 360.0 && r2 >= 119.0 * 119.0;
      const bool surely = clip && std::abs(dx) <= dy - 2.0 && r2 <= 357.0 * 357.0 && r2 >= 123.0 * 123.0;
      if (in[y][x]) {
        ASSERT_TRUE(maybe) << x << "," << y;
      }
      if (surely) {
        ASSERT_TRUE(in[y][x]) << x << "," << y;
      }
    }
  // Row 300 (280 below the apex): the outer circle and the clip decide.
  for (const auto& r : runs)
    if (r.y == 300) {
      EXPECT_EQ(r, (PixelRun{300, 192, 605}));
    }
  // Row 150: the left 45-degree edge at x = 380 - 130 + 1. tan(45 deg) is
  // 0.9999999999999999; PLUS's tolerant ceiling still gives 251 (a plain
  // ceiling would give 252).
  for (const auto& r : runs)
    if (r.y == 150) {
      EXPECT_EQ(r.x0, 251);
    }
  // Rows above the apex and near it (inside the inner radius) are empty.
  for (const auto& r : runs) EXPECT_GT(r.y, 20 + 84);
}

TEST(PixelRuns, InnerRadiusSplitsARow) {
  ReconSettings s;
  s.fanAnglesDeg = {-60, 60};
  s.fanOriginPx = {50, 0};
  s.fanRadiusStartPx = 20;
  s.fanRadiusStopPx = 90;
  const auto runs = pixelRuns(101, 100, s);
  int split = 0;
  for (std::size_t k = 1; k < runs.size(); ++k)
    if (runs[k].y == runs[k - 1].y) {
      ++split;
      EXPECT_LT(runs[k - 1].x1, 50);
      EXPECT_GT(runs[k].x0, 50);
    }
  EXPECT_GT(split, 5);
}

// ---------------------------------------------------------------------------
// Reconstruction on hand-made poses

// Pixel (i, j) lands exactly on voxel (i, j, 0) of a 1 mm grid.
const Mat4 kIdentityPose = imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, Vec3(0.0));

TEST(SplatPixel, ClipRectangleExcludesOutsidePixels) {
  for (const char* ar : {"float", "plus"})
    for (const char* m : {"nearest", "trilinear"}) {
      ReconSettings s = settingsFor(ar, m, "mean");
      s.clipOrigin = {5, 2};
      s.clipSize = {6, 3};
      const Grid g = makeGrid({20, 10, 2}, 1.0);
      auto r = makePixelReconstructor(g, s);
      const auto res = r->insert(makeFrame(20, 10, [](int x, int y) { return 10 + x + y; }), kIdentityPose, 0);
      EXPECT_EQ(res.pixelsInserted, 28u) << ar << m;
      for (int y = 0; y < 10; ++y)
        for (int x = 0; x < 20; ++x) {
          const bool inside = x >= 5 && x <= 11 && y >= 2 && y <= 5;
          const std::size_t i = g.linear(x, y, 0);
          EXPECT_EQ(r->covered(i), inside) << ar << m << " " << x << "," << y;
          EXPECT_EQ(at(r->output(), i), inside ? float(10 + x + y) : 0.0f) << ar << m << " " << x << "," << y;
        }
    }
}

TEST(SplatPixel, FanExcludesOutsidePixels) {
  ReconSettings s = settingsFor("float", "nearest", "mean");
  s.fanAnglesDeg = {-30, 30};
  s.fanOriginPx = {20, 0};
  s.fanRadiusStartPx = 5;
  s.fanRadiusStopPx = 30;
  const Grid g = makeGrid({41, 40, 1}, 1.0);
  auto r = makePixelReconstructor(g, s);
  const auto runs = pixelRuns(41, 40, s);
  std::uint64_t count = 0;
  std::vector<bool> in(41 * 40, false);
  for (const auto& run : runs)
    for (int x = run.x0; x <= run.x1; ++x, ++count) in[run.y * 41 + x] = true;
  const auto res = r->insert(makeFrame(41, 40, [](int, int) { return 9; }), kIdentityPose, 0);
  EXPECT_EQ(res.pixelsInserted, count);
  for (int y = 0; y < 40; ++y)
    for (int x = 0; x < 41; ++x) EXPECT_EQ(r->covered(g.linear(x, y, 0)), bool(in[y * 41 + x])) << x << "," << y;
  EXPECT_FALSE(r->covered(g.linear(20, 3, 0)));   // inside the inner radius
  EXPECT_FALSE(r->covered(g.linear(2, 10, 0)));   // outside the angle
  EXPECT_TRUE(r->covered(g.linear(20, 20, 0)));
}

TEST(SplatPixel, PixelRejection) {
  for (const char* ar : {"float", "plus"})
    for (const char* m : {"nearest", "trilinear"}) {
      ReconSettings s = settingsFor(ar, m, "mean");
      s.pixelRejectionThreshold = 55;  // pixels 0..50 are rejected
      const Grid g = makeGrid({16, 1, 1}, 1.0);
      auto r = makePixelReconstructor(g, s);
      const auto res = r->insert(makeFrame(16, 1, [](int x, int) { return 10 * x; }), kIdentityPose, 0);
      EXPECT_EQ(res.pixelsInserted, 10u) << ar << m;
      for (int x = 0; x < 16; ++x) EXPECT_EQ(r->covered(std::size_t(x)), x >= 6) << ar << m << " " << x;
    }
}

TEST(SplatPixel, ConstantImageReconstructsToTheConstant) {
  for (const Combo& c : allCombos()) {
    std::mt19937 rng(7);
    const Grid g = makeGrid({30, 28, 26}, 0.5);
    auto r = makePixelReconstructor(g, settingsFor(c.arithmetic, c.method, c.compounding));
    const Frame f = makeFrame(48, 40, [](int, int) { return 173; });
    for (int k = 0; k < 6; ++k) r->insert(f, randomPose(rng, 48, 40, 0.3, Vec3(7.0, 7.0, 6.0), 2.0), 0);
    std::size_t covered = 0;
    for (std::size_t i = 0; i < g.voxelCount(); ++i) {
      const float v = at(r->output(), i);
      if (r->covered(i)) {
        ++covered;
        // float MEAN divides a float sum by a float weight: not always exact.
        const double tol = std::string(c.arithmetic) == "float" && std::string(c.compounding) == "mean" ? 1e-3 : 0.0;
        ASSERT_NEAR(v, 173.0, tol) << name(c) << " voxel " << i;
      } else {
        // PLUS keeps a trilinear MEAN voxel's value even when its rounded
        // accumulator is 0 (total weight < 1/512); it is not covered.
        ASSERT_TRUE(v == 0.0f || v == 173.0f) << name(c) << " voxel " << i;
        if (std::string(c.arithmetic) == "float") {
          ASSERT_EQ(v, 0.0f) << name(c);
        }
      }
    }
    EXPECT_GT(covered, 2000u) << name(c);
  }
}

TEST(SplatPixel, SixteenBitFramesInFloat) {
  const Grid g = makeGrid({10, 10, 1}, 1.0);
  for (const char* m : {"nearest", "trilinear"}) {
    auto r = makePixelReconstructor(g, settingsFor("float", m, "mean"));
    r->insert(makeFrame(10, 10, [](int x, int) { return 1000 + 1000 * x; }, PixelType::U16), kIdentityPose, 0);
    for (int x = 0; x < 10; ++x) EXPECT_EQ(at(r->output(), g.linear(x, 3, 0)), float(1000 + 1000 * x)) << m;
  }
}

// One pixel at a known fractional voxel position.
TEST(SplatPixel, TrilinearWeightsFloat) {
  const Grid g = makeGrid({6, 6, 6}, 1.0);
  for (const Vec3 p : {Vec3(2.25, 3.5, 1.75), Vec3(2.3, 3.7, 1.1), Vec3(0.01, 4.999, 2.5)}) {
    auto r = makePixelReconstructor(g, settingsFor("float", "trilinear", "mean"));
    const auto res = r->insert(makeFrame(1, 1, [](int, int) { return 200; }),
                               imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, p), 0);
    EXPECT_EQ(res.pixelsInserted, 1u);
    const Volume w = r->weights();
    const Vec3 n0 = glm::floor(p), f = p - n0;
    double sum = 0;
    for (int k = 0; k < 8; ++k) {
      const Index3 c = Index3(n0) + Index3(k & 1, (k >> 1) & 1, (k >> 2) & 1);
      const double expect = ((k & 1) ? f.x : 1 - f.x) * ((k & 2) ? f.y : 1 - f.y) * ((k & 4) ? f.z : 1 - f.z);
      const std::size_t i = g.linear(c.x, c.y, c.z);
      EXPECT_NEAR(at(w, i), expect, 1e-6) << p.x << " corner " << k;
      sum += at(w, i);
      if (expect > 0) {
        EXPECT_NEAR(at(r->output(), i), 200.0, 1e-4);  // (w * 200) / w in float
      }
    }
    EXPECT_NEAR(sum, 1.0, 1e-6);
    double total = 0;
    for (std::size_t i = 0; i < g.voxelCount(); ++i) total += at(w, i);
    EXPECT_NEAR(total, 1.0, 1e-6) << "weight outside the 8 corners";
  }
}

// PLUS's 14-bit weights (§4): w = mul(r_x, mul(r_y, r_z)) etc., and the
// accumulator gets round(w * 256).
TEST(SplatPixel, TrilinearWeightsPlus) {
  const Grid g = makeGrid({6, 6, 6}, 1.0);
  auto r = makePixelReconstructor(g, settingsFor("plus", "trilinear", "mean"));
  const Vec3 p(2.25, 3.5, 1.75);
  r->insert(makeFrame(1, 1, [](int, int) { return 200; }), imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, p), 0);
  auto mul = [](std::int64_t a, std::int64_t b) { return (a * b + 8192) >> 14; };
  const std::int64_t fx = 4096, fy = 8192, fz = 12288;  // 0.25, 0.5, 0.75
  const std::int64_t rx = 16384 - fx, ry = 16384 - fy, rz = 16384 - fz;
  const Volume w = r->weights();
  for (int k = 0; k < 8; ++k) {
    const int bx = k & 1, by = (k >> 1) & 1, bz = (k >> 2) & 1;
    const std::int64_t wk = mul(bx ? fx : rx, mul(by ? fy : ry, bz ? fz : rz));
    const std::size_t i = g.linear(2 + bx, 3 + by, 1 + bz);
    EXPECT_EQ(at(w, i), float((wk + 32) >> 6) / 256.0f) << k;
    EXPECT_EQ(at(r->output(), i), 200.0f);
  }
}

// Float keeps every in-bounds corner at the volume border; PLUS drops the pixel.
TEST(SplatPixel, TrilinearAtTheBorder) {
  const Grid g = makeGrid({4, 4, 4}, 1.0);
  const Mat4 pose = imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, Vec3(-0.25, 1.0, 3.5));
  auto f = makePixelReconstructor(g, settingsFor("float", "trilinear", "mean"));
  EXPECT_EQ(f->insert(makeFrame(1, 1, [](int, int) { return 80; }), pose, 0).pixelsInserted, 1u);
  const Volume w = f->weights();
  EXPECT_NEAR(at(w, g.linear(0, 1, 3)), 0.75 * 0.5, 1e-6);
  EXPECT_NEAR(at(w, g.linear(0, 1, 2)), 0.0, 1e-6);
  EXPECT_EQ(at(f->output(), g.linear(0, 1, 3)), 80.0f);
  auto p = makePixelReconstructor(g, settingsFor("plus", "trilinear", "mean"));
  EXPECT_EQ(p->insert(makeFrame(1, 1, [](int, int) { return 80; }), pose, 0).pixelsInserted, 0u);
  EXPECT_FALSE(p->covered(g.linear(0, 1, 3)));
}

TEST(SplatPixel, FloatMeanHasNoSaturation) {
  const Grid g = makeGrid({3, 3, 3}, 1.0);
  const Mat4 pose = imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, Vec3(1.0));
  const Frame lo = makeFrame(1, 1, [](int, int) { return 100; }), hi = makeFrame(1, 1, [](int, int) { return 200; });
  const std::size_t c = g.linear(1, 1, 1);
  for (const char* m : {"nearest", "trilinear"})
    for (int hits : {300, 1000}) {
      auto r = makePixelReconstructor(g, settingsFor("float", m, "mean"));
      for (int k = 0; k < hits; ++k) r->insert(k % 2 ? hi : lo, pose, 0);
      EXPECT_EQ(at(r->output(), c), 150.0f) << m << " " << hits;
      EXPECT_EQ(at(r->weights(), c), float(hits)) << m;
    }
}

// PLUS's nearest-neighbour MEAN truncates the running mean at every hit: with
// alternating 100 / 200 it sinks to 100 long before its 16-bit accumulator
// saturates at 255 hits (after which a truncating recursive filter keeps it
// there). Reference: the formula of §3.6, written out here.
TEST(SplatPixel, PlusMeanTruncatesAndSaturates) {
  const Grid g = makeGrid({3, 3, 3}, 1.0);
  const Mat4 pose = imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, Vec3(1.0));
  const Frame lo = makeFrame(1, 1, [](int, int) { return 100; }), hi = makeFrame(1, 1, [](int, int) { return 200; });
  for (int hits : {3, 10, 300, 1000}) {
    auto r = makePixelReconstructor(g, settingsFor("plus", "nearest", "mean"));
    unsigned v = 0, acc = 0;
    for (int k = 0; k < hits; ++k) {
      const unsigned in = k % 2 ? 200 : 100;
      r->insert(k % 2 ? hi : lo, pose, 0);
      if (acc <= 65279) {
        v = (in * 256 + v * acc) / (acc + 256);
        acc += 256;
      } else {
        v = static_cast<unsigned>(in / 256.0 + v * 255.0 / 256.0);
      }
    }
    const std::size_t c = g.linear(1, 1, 1);
    EXPECT_EQ(at(r->output(), c), float(v)) << hits;
    EXPECT_EQ(at(r->weights(), c), float(acc) / 256.0f) << hits;
  }
  auto r = makePixelReconstructor(g, settingsFor("plus", "nearest", "mean"));
  for (int k = 0; k < 300; ++k) r->insert(k % 2 ? hi : lo, pose, 0);
  EXPECT_EQ(at(r->output(), g.linear(1, 1, 1)), 100.0f);  // the exact mean is 150
  EXPECT_EQ(at(r->weights(), g.linear(1, 1, 1)), 255.0f);  // saturated
}

TEST(SplatPixel, LatestAndMaximum) {
  const Grid g = makeGrid({3, 3, 3}, 1.0);
  const Mat4 pose = imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, Vec3(1.0));
  const std::size_t c = g.linear(1, 1, 1);
  for (const char* ar : {"float", "plus"})
    for (const char* m : {"nearest", "trilinear"}) {
      auto latest = makePixelReconstructor(g, settingsFor(ar, m, "latest"));
      auto maximum = makePixelReconstructor(g, settingsFor(ar, m, "maximum"));
      for (int v : {50, 90, 30}) {
        const Frame f = makeFrame(1, 1, [v](int, int) { return v; });
        latest->insert(f, pose, 0);
        maximum->insert(f, pose, 0);
      }
      EXPECT_EQ(at(latest->output(), c), 30.0f) << ar << m;
      EXPECT_EQ(at(maximum->output(), c), 90.0f) << ar << m;
    }
  // Trilinear: a corner whose weight is below 1/8 is not set.
  for (const char* ar : {"float", "plus"}) {
    auto r = makePixelReconstructor(g, settingsFor(ar, "trilinear", "latest"));
    // weights 0.95 / 0.05 along x (y, z on the voxel)
    r->insert(makeFrame(1, 1, [](int, int) { return 77; }),
              imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, Vec3(0.05, 1.0, 1.0)), 0);
    EXPECT_EQ(at(r->output(), g.linear(0, 1, 1)), 77.0f) << ar;
    EXPECT_FALSE(r->covered(g.linear(1, 1, 1))) << ar;
    EXPECT_EQ(at(r->output(), g.linear(1, 1, 1)), 0.0f) << ar;
  }
}

// ---------------------------------------------------------------------------
// Threads, incremental output, dirty regions

struct Scene {
  Grid grid = makeGrid({40, 36, 32}, 0.5);
  std::vector<Frame> frames;
  std::vector<Mat4> poses;
};

Scene randomScene(unsigned seed, int count = 6) {
  Scene s;
  std::mt19937 rng(seed);
  s.frames = randomFrames(rng, count, 64, 48);
  for (int k = 0; k < count; ++k) s.poses.push_back(randomPose(rng, 64, 48, 0.37, Vec3(10.0, 9.0, 8.0), 6.0));
  // One frame exactly in a grid plane (rows and columns along grid axes).
  s.poses[1] = imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 0.25, Vec3(1.0, 1.5, 7.5));
  return s;
}

ReconSettings sceneSettings(const Combo& c, int threads) {
  ReconSettings s = settingsFor(c.arithmetic, c.method, c.compounding, threads);
  s.clipOrigin = {4, 2};
  s.clipSize = {56, 42};
  s.fanAnglesDeg = {-50, 40};
  s.fanOriginPx = {30, -5};
  s.fanRadiusStartPx = 8;
  s.fanRadiusStopPx = 60;
  return s;
}

TEST(SplatPixel, AnyThreadCountGivesTheSameBits) {
  const Scene sc = randomScene(11);
  for (const Combo& c : allCombos()) {
    Volume ref, refW;
    std::vector<std::uint64_t> refPixels;
    for (int t : {1, 2, 3, 7}) {
      ReconSettings s = sceneSettings(c, t);
      // Hole filling runs on threads too (two combinations keep the test short).
      s.pixel.fillHoles = name(c) == "float/trilinear/mean" || name(c) == "plus/nearest/mean";
      s.pixel.fillHolesIncremental = true;
      auto r = makePixelReconstructor(sc.grid, s);
      std::vector<std::uint64_t> pixels;
      for (std::size_t k = 0; k < sc.frames.size(); ++k)
        pixels.push_back(r->insert(sc.frames[k], sc.poses[k], 0).pixelsInserted);
      if (t == 1) {
        ref = r->output();
        refW = r->weights();
        refPixels = pixels;
        continue;
      }
      EXPECT_TRUE(r->output().bytes == ref.bytes) << name(c) << " threads " << t;
      EXPECT_TRUE(r->weights().bytes == refW.bytes) << name(c) << " threads " << t;
      EXPECT_EQ(pixels, refPixels) << name(c) << " threads " << t;
    }
  }
}

TEST(SplatPixel, IncrementalEqualsBatchAndDirtyCoversEveryChange) {
  const Scene sc = randomScene(23);
  for (const Combo& c : allCombos())
    for (bool fill : {false, true}) {
      if (fill && std::string(c.compounding) != "mean") continue;  // (keeps the test short)
      ReconSettings s = sceneSettings(c, 2);
      s.pixel.fillHoles = fill;
      s.pixel.fillHolesIncremental = true;
      auto r = makePixelReconstructor(sc.grid, s);
      Volume before = r->output();
      Volume beforeW = r->weights();
      for (std::size_t k = 0; k < sc.frames.size(); ++k) {
        const InsertResult res = r->insert(sc.frames[k], sc.poses[k], 0);
        const Volume& after = r->output();
        const Volume afterW = r->weights();
        std::size_t changed = 0;
        for (std::int64_t z = 0; z < sc.grid.dims.z; ++z)
          for (std::int64_t y = 0; y < sc.grid.dims.y; ++y)
            for (std::int64_t x = 0; x < sc.grid.dims.x; ++x) {
              const std::size_t i = sc.grid.linear(x, y, z);
              const bool diff = std::memcmp(&after.bytes[4 * i], &before.bytes[4 * i], 4) != 0 ||
                                std::memcmp(&afterW.bytes[4 * i], &beforeW.bytes[4 * i], 4) != 0;
              if (!diff) continue;
              ++changed;
              ASSERT_TRUE(res.dirty.containsVoxel(x, y, z))
                  << name(c) << (fill ? " fill" : "") << " frame " << k << " voxel " << x << "," << y << "," << z;
            }
        EXPECT_GT(changed, 0u) << name(c) << " frame " << k;
        // The region is the bricks of the frame, not the grid.
        EXPECT_LT(res.dirty.voxelCount(), sc.grid.voxelCount()) << name(c);
        before = after;
        beforeW = afterW;
      }
      // A fresh reconstructor fed every frame at once ends with the same bits.
      auto batch = makePixelReconstructor(sc.grid, s);
      for (std::size_t k = 0; k < sc.frames.size(); ++k) batch->insert(sc.frames[k], sc.poses[k], 0);
      EXPECT_TRUE(batch->output().bytes == r->output().bytes) << name(c);
    }
}

// A frame that misses the grid changes nothing and dirties nothing.
TEST(SplatPixel, FrameOutsideTheGrid) {
  const Grid g = makeGrid({8, 8, 8}, 1.0);
  for (const Combo& c : allCombos()) {
    auto r = makePixelReconstructor(g, settingsFor(c.arithmetic, c.method, c.compounding));
    const auto res = r->insert(makeFrame(10, 10, [](int, int) { return 5; }),
                               imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, Vec3(100.0, 0.0, 0.0)), 0);
    EXPECT_EQ(res.pixelsInserted, 0u) << name(c);
    EXPECT_TRUE(res.dirty.empty()) << name(c);
  }
}

// ---------------------------------------------------------------------------
// Bad input

TEST(SplatPixel, InvalidInputThrowsAndChangesNothing) {
  const Grid g = makeGrid({8, 8, 8}, 1.0);
  for (const char* ar : {"float", "plus"}) {
    auto r = makePixelReconstructor(g, settingsFor(ar, "trilinear", "mean"));
    const Frame good = makeFrame(4, 4, [](int, int) { return 50; });
    const Mat4 pose = imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, Vec3(2.0));
    r->insert(good, pose, 0);
    const Volume before = r->output();

    Frame empty;
    EXPECT_THROW(r->insert(empty, pose, 0), InputError) << ar;
    Frame shortFrame = good;
    shortFrame.pixels.resize(5);
    EXPECT_THROW(r->insert(shortFrame, pose, 0), InputError) << ar;
    Mat4 nan = pose;
    nan[3][1] = std::numeric_limits<double>::quiet_NaN();
    EXPECT_THROW(r->insert(good, nan, 0), InputError) << ar;
    Mat4 inf = pose;
    inf[0][0] = std::numeric_limits<double>::infinity();
    EXPECT_THROW(r->insert(good, inf, 0), InputError) << ar;
    Mat4 far = pose;
    far[3][0] = 1e300;
    EXPECT_THROW(r->insert(good, far, 0), InputError) << ar;
    EXPECT_TRUE(r->output().bytes == before.bytes) << ar;
  }
  // The plus arithmetic has 8-bit voxels and a 14-bit fixed-point range.
  auto p = makePixelReconstructor(g, settingsFor("plus", "nearest", "mean"));
  EXPECT_THROW(p->insert(makeFrame(2, 2, [](int, int) { return 1; }, PixelType::U16), kIdentityPose, 0), InputError);
  EXPECT_THROW(p->insert(makeFrame(2, 2, [](int, int) { return 1; }),
                         imagePose(Vec3(1, 0, 0), Vec3(0, 1, 0), 1.0, Vec3(2e5, 0, 0)), 0),
               InputError);
  // Settings.
  EXPECT_THROW(settingsFor("float", "nearest", "median"), InputError);  // refused where the name is read
  ReconSettings bad = settingsFor("float", "nearest", "mean");
  bad.pixel.compounding = static_cast<pp5::gp::Compounding>(7);  // and settings built in code are checked too
  EXPECT_THROW(makePixelReconstructor(g, bad), InputError);
  bad = settingsFor("float", "nearest", "mean");
  bad.pixel.fillHoles = true;
  bad.pixel.holeFilling = {PlusHoleFillingElement{PlusHoleFillingType::Gaussian, 0, 1.0, 0.5, 9, 1}};
  EXPECT_THROW(makePixelReconstructor(g, bad), InputError);
}

// ---------------------------------------------------------------------------
// PLUS's number formats

TEST(PlusMath, FixedPointAndTolerantFloor) {
  using namespace plusmath;
  EXPECT_EQ(toFixed(1.0), 16384);
  EXPECT_EQ(toFixed(0.5 / 16384), 0);   // ties to even
  EXPECT_EQ(toFixed(1.5 / 16384), 2);
  EXPECT_EQ(toFixed(-1.5 / 16384), -2);
  EXPECT_EQ(mul(16384, 8192), 8192);
  EXPECT_EQ(mul(1, 8192), 1);  // rounds half up
  EXPECT_EQ(roundToInt(toFixed(2.5)), 3);
  EXPECT_EQ(roundToInt(toFixed(-2.5)), -2);
  EXPECT_EQ(floorPlus(3.0 - 1e-6), 3);  // within 2^-17 below an integer
  EXPECT_EQ(floorPlus(3.0 - 1e-4), 2);
  EXPECT_EQ(floorPlus(-0.5), -1);
  EXPECT_EQ(ceilPlus(251.00000000000003), 251);
  EXPECT_EQ(ceilPlus(251.001), 252);
}

TEST(PlusMath, DivisionBySmallReciprocalIsExact) {
  std::uint64_t wrong = 0;
  for (std::uint32_t k = 1; k < 256; ++k)
    for (std::uint32_t n = 0; n < 65536; ++n) wrong += plusmath::divSmall(n, k) != n / k;
  EXPECT_EQ(wrong, 0u);
}

}  // namespace
