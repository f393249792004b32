// The slice geometry (reconstruction/slice_geometry.hpp): a frame's reach and the fill-in
// slices' reach hold every point the tent kernel can write, and stay within a
// pad of the exact hull; checked against sampled kernel points and against
// the voxels a real tent splat changes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <glm/gtc/quaternion.hpp>

#include "core/error.hpp"
#include "core/frame.hpp"
#include "core/grid.hpp"
#include "formats/volume_io.hpp"
#include "reconstruction/reconstruction.hpp"
#include "reconstruction/slice_geometry.hpp"
#include "reconstruction/splat_tent.hpp"

namespace {

using pp5::Grid;
using pp5::Index3;
using pp5::InputError;
using pp5::Mat4;
using pp5::Vec3;
using pp5::gp::Box3;
using pp5::gp::ReconSettings;
using pp5::gp::WorldBox;

// ------------------------------------------------------------------ reach --

struct Axes {
  Vec3 origin, ex, ey, u, v, n;
};

// The slice's axes as the tent splat defines them (SlicePose).
Axes axesOf(const Mat4& m) {
  Axes a;
  a.origin = Vec3(m[3]);
  a.ex = Vec3(m[0]);
  a.ey = Vec3(m[1]);
  a.u = glm::normalize(a.ex);
  a.n = glm::normalize(glm::cross(a.ex, a.ey));
  a.v = glm::cross(a.n, a.u);
  return a;
}

glm::dmat3 randomRotation(std::mt19937& rng) {
  std::normal_distribution<double> nd;
  glm::dquat q(nd(rng), nd(rng), nd(rng), nd(rng));
  return glm::mat3_cast(glm::normalize(q));
}

glm::dmat3 axisAngle(Vec3 axis, double rad) { return glm::mat3_cast(glm::angleAxis(rad, glm::normalize(axis))); }

// An image-to-reference matrix: pixel (c, r) at origin + c ex + r ey.
Mat4 imageMatrix(const Vec3& origin, const Vec3& ex, const Vec3& ey) {
  Mat4 m(1.0);
  m[0] = glm::dvec4(ex, 0.0);
  m[1] = glm::dvec4(ey, 0.0);
  m[2] = glm::dvec4(glm::normalize(glm::cross(ex, ey)), 0.0);
  m[3] = glm::dvec4(origin, 1.0);
  return m;
}

// A random pose: a rotation, pixel sizes, sometimes a shear or unequal
// scales, the origin anywhere near the grid.
Mat4 randomPose(std::mt19937& rng, int kind) {
  std::uniform_real_distribution<double> U(0.0, 1.0);
  const glm::dmat3 r = randomRotation(rng);
  const double sx = 0.05 + 0.5 * U(rng), sy = 0.05 + 0.5 * U(rng);
  const double shear = kind % 3 == 2 ? (U(rng) - 0.5) * 0.6 : 0.0;
  const Vec3 origin = Vec3(U(rng), U(rng), U(rng)) * 100.0 - 50.0;
  return imageMatrix(origin, sx * r[0], shear * r[0] + sy * r[1]);
}

ReconSettings randomRecon(std::mt19937& rng, int width, int height) {
  std::uniform_real_distribution<double> U(0.0, 1.0);
  ReconSettings s;
  s.tent.kernelLateralMm = 0.2 + 3.0 * U(rng);
  s.tent.kernelAxialMm = 0.2 + 2.0 * U(rng);
  s.tent.kernelElevationMm = 0.2 + 4.0 * U(rng);
  const int kind = static_cast<int>(U(rng) * 4);
  if (kind == 1) {  // inside the frame
    s.clipOrigin = glm::ivec2(static_cast<int>(U(rng) * width / 2), static_cast<int>(U(rng) * height / 2));
    s.clipSize = glm::ivec2(1 + static_cast<int>(U(rng) * width / 2), 1 + static_cast<int>(U(rng) * height / 2));
  } else if (kind == 2) {  // over the edges
    s.clipOrigin = glm::ivec2(static_cast<int>(U(rng) * width) - width / 3, static_cast<int>(U(rng) * height) - height / 3);
    s.clipSize = glm::ivec2(width, height);
  } else if (kind == 3) {  // one size 0: no clipping
    s.clipOrigin = glm::ivec2(3, 4);
    s.clipSize = glm::ivec2(0, 10);
  }
  return s;
}

// The clipped pixel rectangle, inclusive (fan_mask.hpp's rule, written out).
struct Rect {
  double x0, y0, x1, y1;
};
Rect clippedRect(int w, int h, const ReconSettings& s) {
  Rect r{0, 0, w - 1.0, h - 1.0};
  if (s.clipSize.x > 0 && s.clipSize.y > 0) {
    r.x0 = std::max(0, s.clipOrigin.x);
    r.y0 = std::max(0, s.clipOrigin.y);
    r.x1 = std::min(w - 1, s.clipOrigin.x + s.clipSize.x);
    r.y1 = std::min(h - 1, s.clipOrigin.y + s.clipSize.y);
  }
  return r;
}

struct Hull {
  Vec3 lo{std::numeric_limits<double>::infinity()}, hi{-std::numeric_limits<double>::infinity()};
  void add(const Vec3& p) {
    lo = glm::min(lo, p);
    hi = glm::max(hi, p);
  }
};

bool inside(const WorldBox& b, const Vec3& p) {
  return p.x >= b.lo.x && p.y >= b.lo.y && p.z >= b.lo.z && p.x <= b.hi.x && p.y <= b.hi.y && p.z <= b.hi.z;
}

// Points of the clipped pixel rectangle (corners, edges, random interior),
// each moved by kernel offsets (corners, random), in slice coordinates of a
// pose with axes (ex, ey) and orthonormal (u, v, n): callback(c, r, du, dv, dn).
template <typename F>
void forReachPoints(std::mt19937& rng, const Rect& r, const ReconSettings& s, F&& f) {
  std::uniform_real_distribution<double> U(0.0, 1.0);
  std::vector<std::pair<double, double>> px;
  for (const double c : {r.x0, r.x1})
    for (const double y : {r.y0, r.y1}) px.emplace_back(c, y);
  for (int i = 0; i < 12; ++i) px.emplace_back(r.x0 + (r.x1 - r.x0) * U(rng), r.y0 + (r.y1 - r.y0) * U(rng));
  std::vector<Vec3> ks;
  for (int c = 0; c < 8; ++c)
    ks.emplace_back((c & 1) ? s.tent.kernelLateralMm : -s.tent.kernelLateralMm, (c & 2) ? s.tent.kernelAxialMm : -s.tent.kernelAxialMm,
                    (c & 4) ? s.tent.kernelElevationMm : -s.tent.kernelElevationMm);
  for (int i = 0; i < 6; ++i)
    ks.emplace_back((2 * U(rng) - 1) * s.tent.kernelLateralMm, (2 * U(rng) - 1) * s.tent.kernelAxialMm,
                    (2 * U(rng) - 1) * s.tent.kernelElevationMm);
  for (const auto& [c, y] : px)
    for (const Vec3& k : ks) f(c, y, k);
}

// The pad frameReach adds beyond the exact hull: 1e-3 mm plus 1e-9 of the
// box's largest coordinate along the axis (and rounding).
double padBound(const WorldBox& b, int i) {
  return 1e-3 + 2e-9 * std::max(std::abs(b.lo[i]), std::abs(b.hi[i])) + 1e-12;
}

TEST(FrameReach, HoldsEveryKernelPointAndIsTheHullPlusAPad) {
  std::mt19937 rng(1990);
  std::uniform_int_distribution<int> size(1, 240);
  for (int trial = 0; trial < 600; ++trial) {
    SCOPED_TRACE(testing::Message() << "trial " << trial);
    const int w = size(rng), h = size(rng);
    const ReconSettings s = randomRecon(rng, w, h);
    const Mat4 m = randomPose(rng, trial);
    const Axes a = axesOf(m);
    const WorldBox box = pp5::gp::frameReach(m, w, h, s);
    Hull hull;
    forReachPoints(rng, clippedRect(w, h, s), s, [&](double c, double r, const Vec3& k) {
      const Vec3 p = a.origin + c * a.ex + r * a.ey + k.x * a.u + k.y * a.v + k.z * a.n;
      hull.add(p);
      ASSERT_TRUE(inside(box, p)) << "pixel " << c << "," << r << " + kernel " << k.x << "," << k.y << "," << k.z;
    });
    // The corners of pixels and kernel are in the hull, so it is exact: the box
    // exceeds it by the pad only.
    for (int i = 0; i < 3; ++i) {
      EXPECT_LE(hull.lo[i] - box.lo[i], padBound(box, i));
      EXPECT_LE(box.hi[i] - hull.hi[i], padBound(box, i));
    }
  }
}

TEST(FrameReach, ClipRectangleAndErrors) {
  ReconSettings s;
  s.tent.kernelLateralMm = 1.0;
  s.tent.kernelAxialMm = 0.5;
  s.tent.kernelElevationMm = 2.0;
  // Identity pose: pixel (c, r) at (c, r, 0) mm.
  const Mat4 id(1.0);
  WorldBox b = pp5::gp::frameReach(id, 100, 50, s);
  EXPECT_NEAR(b.lo.x, -1.0, 1.1e-3);
  EXPECT_NEAR(b.hi.x, 100.0, 1.1e-3);
  EXPECT_NEAR(b.lo.y, -0.5, 1.1e-3);
  EXPECT_NEAR(b.hi.y, 49.5, 1.1e-3);
  EXPECT_NEAR(b.lo.z, -2.0, 1.1e-3);
  EXPECT_NEAR(b.hi.z, 2.0, 1.1e-3);
  s.clipOrigin = glm::ivec2(10, 20);
  s.clipSize = glm::ivec2(30, 5);  // columns 10..40, rows 20..25, as PLUS counts them
  b = pp5::gp::frameReach(id, 100, 50, s);
  EXPECT_NEAR(b.lo.x, 9.0, 1.1e-3);
  EXPECT_NEAR(b.hi.x, 41.0, 1.1e-3);
  EXPECT_NEAR(b.lo.y, 19.5, 1.1e-3);
  EXPECT_NEAR(b.hi.y, 25.5, 1.1e-3);
  s.clipOrigin = glm::ivec2(200, 20);  // misses the frame: nothing is selected, the whole frame is taken
  b = pp5::gp::frameReach(id, 100, 50, s);
  EXPECT_NEAR(b.hi.x, 100.0, 1.1e-3);
  Mat4 flat(1.0);
  flat[1] = glm::dvec4(2.0, 0.0, 0.0, 0.0);  // y along x
  EXPECT_THROW(pp5::gp::frameReach(flat, 10, 10, s), InputError);
  Mat4 nan(1.0);
  nan[3][0] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(pp5::gp::frameReach(nan, 10, 10, s), InputError);
  EXPECT_THROW(pp5::gp::frameReach(id, 0, 10, s), InputError);
}

// interpolatePose (reconstruction/splat_tent.cpp), written out: origin linear, rotation
// by slerp the short way, pixel steps linear.
struct SliceAt {
  Vec3 origin, u, v, n;
  double sx, eyu, syv;
  Vec3 point(double c, double r, const Vec3& k) const {
    return origin + (c * sx + r * eyu + k.x) * u + (r * syv + k.y) * v + k.z * n;
  }
};
SliceAt sliceOf(const Mat4& m) {
  const Axes a = axesOf(m);
  return {a.origin, a.u, a.v, a.n, glm::length(a.ex), glm::dot(a.ey, a.u), glm::dot(a.ey, a.v)};
}
SliceAt interpolate(const SliceAt& a, const SliceAt& b, double t) {
  const glm::dquat qa = glm::normalize(glm::quat_cast(glm::dmat3(a.u, a.v, a.n)));
  glm::dquat qb = glm::normalize(glm::quat_cast(glm::dmat3(b.u, b.v, b.n)));
  if (glm::dot(qa, qb) < 0.0) qb = -qb;
  const glm::dmat3 r = glm::mat3_cast(glm::normalize(glm::slerp(qa, qb, t)));
  return {a.origin + (b.origin - a.origin) * t, r[0], r[1], r[2], a.sx + (b.sx - a.sx) * t,
          a.eyu + (b.eyu - a.eyu) * t, a.syv + (b.syv - a.syv) * t};
}

// The second frame: the first turned by up to 20 degrees about a random axis
// through a random pivot (often far off, to make the sagitta count), moved,
// and sometimes with other pixel sizes or shear.
Mat4 nextPose(std::mt19937& rng, const Mat4& m, double maxDeg, int kind) {
  std::uniform_real_distribution<double> U(0.0, 1.0);
  std::normal_distribution<double> nd;
  const double rad = maxDeg * U(rng) * 3.14159265358979323846 / 180.0;
  const glm::dmat3 r = axisAngle(Vec3(nd(rng), nd(rng), nd(rng)), rad);
  const Vec3 pivot = Vec3(m[3]) + Vec3(nd(rng), nd(rng), nd(rng)) * 40.0;
  const Vec3 shift = Vec3(nd(rng), nd(rng), nd(rng)) * 2.0;
  Vec3 ex = r * Vec3(m[0]), ey = r * Vec3(m[1]);
  if (kind % 4 == 3) {
    ex *= 0.8 + 0.4 * U(rng);
    ey = ey * (0.8 + 0.4 * U(rng)) + (U(rng) - 0.5) * 0.2 * glm::normalize(ex);
  }
  return imageMatrix(pivot + r * (Vec3(m[3]) - pivot) + shift, ex, ey);
}

// Calls inReach(i, j, k) for every voxel whose weight differs between the
// two volumes; the first voxel for which it returns false fails the test
// (naming the voxel) and ends the scan.
template <typename F>
void forEachChangedVoxel(const Grid& g, const pp5::Volume& before, const pp5::Volume& after, F inReach) {
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j)
      for (std::int64_t i = 0; i < g.dims.x; ++i) {
        const std::size_t l = g.linear(i, j, k);
        if (after.value(l) == before.value(l)) continue;
        if (!inReach(i, j, k)) {
          ADD_FAILURE() << "voxel " << i << "," << j << "," << k << " changed outside the reach";
          return;
        }
      }
}

TEST(FillInReach, HoldsEverySlerpedSliceAndStaysNearTheHull) {
  std::mt19937 rng(1991);
  std::uniform_int_distribution<int> size(1, 240);
  double worstRatio = 0.0;
  int grown = 0;
  for (int trial = 0; trial < 400; ++trial) {
    SCOPED_TRACE(testing::Message() << "trial " << trial);
    const int w = size(rng), h = size(rng);
    ReconSettings s = randomRecon(rng, w, h);
    s.tent.fillInMaxAngleDeg = 20.0;
    const Mat4 m0 = randomPose(rng, trial);
    const Mat4 m1 = nextPose(rng, m0, 20.0, trial);
    const WorldBox box = pp5::gp::fillInReach(m0, m1, w, h, s);
    const SliceAt a = sliceOf(m0), b = sliceOf(m1);
    const Rect rect = clippedRect(w, h, s);
    Hull hull, ends;
    for (int i = 0; i <= 64; ++i) {
      const double t = i / 64.0;
      const SliceAt p = interpolate(a, b, t);
      forReachPoints(rng, rect, s, [&](double c, double r, const Vec3& k) {
        const Vec3 x = p.point(c, r, k);
        hull.add(x);
        if (i == 0 || i == 64) ends.add(x);
        ASSERT_TRUE(inside(box, x)) << "t " << t << " pixel " << c << "," << r;
      });
      if (HasFatalFailure()) return;
    }
    for (int i = 0; i < 3; ++i)
      if (hull.lo[i] < ends.lo[i] - 1e-6 || hull.hi[i] > ends.hi[i] + 1e-6) {
        ++grown;  // the slerped slices leave the two frames' box here
        break;
      }
    // The bound: each face at most 1e-4 rho + 0.005 |p0 - p1| + the pad
    // beyond the hull of the sampled slices, rho the largest distance of a
    // frame's reach point from the pose origin, |p0 - p1| the largest change
    // of a pixel corner's slice coordinates (the sagitta of 1 degree steps,
    // 3.8e-5 rho, plus that of the test's own 64 steps in t). It is also
    // within the coarse bound of growing the two frames' union by the whole
    // rotation's sagitta: rho (1 - cos(a) + a - sin(a)) + sin(a)/2 |p0 - p1|,
    // a = theta / 2.
    const glm::dquat qa = glm::quat_cast(glm::dmat3(a.u, a.v, a.n)), qb = glm::quat_cast(glm::dmat3(b.u, b.v, b.n));
    const double half = std::acos(std::min(1.0, std::abs(glm::dot(glm::normalize(qa), glm::normalize(qb)))));
    double rho = 0.0, dmax = 0.0;
    const SliceAt a0{Vec3(0.0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1), a.sx, a.eyu, a.syv};
    const SliceAt b0{Vec3(0.0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1), b.sx, b.eyu, b.syv};
    for (const double c : {rect.x0, rect.x1})
      for (const double r : {rect.y0, rect.y1}) {
        dmax = std::max(dmax, glm::length(a0.point(c, r, Vec3(0.0)) - b0.point(c, r, Vec3(0.0))));
        for (int k = 0; k < 8; ++k) {
          const Vec3 kk((k & 1) ? s.tent.kernelLateralMm : -s.tent.kernelLateralMm, (k & 2) ? s.tent.kernelAxialMm : -s.tent.kernelAxialMm,
                        (k & 4) ? s.tent.kernelElevationMm : -s.tent.kernelElevationMm);
          rho = std::max({rho, glm::length(a0.point(c, r, kk)), glm::length(b0.point(c, r, kk))});
        }
      }
    const double bound = rho * (1.0 - std::cos(half) + half - std::sin(half)) + 0.5 * std::sin(half) * dmax;
    ASSERT_LE(half, 10.0 * 3.14159265358979323846 / 180.0 + 1e-9);
    for (int i = 0; i < 3; ++i) {
      const double over = std::max(hull.lo[i] - box.lo[i], box.hi[i] - hull.hi[i]);
      EXPECT_LE(over, bound + padBound(box, i));
      EXPECT_LE(over, 1e-4 * rho + 0.005 * dmax + padBound(box, i));
      if (rho > 0) worstRatio = std::max(worstRatio, (over - 1e-3) / rho);
    }
  }
  EXPECT_GT(grown, 20) << "the test never needed the growth";
  RecordProperty("worst_excess_over_rho", std::to_string(worstRatio));
}

TEST(FillInReach, NoGrowthWithoutFillIn) {
  std::mt19937 rng(3);
  for (int trial = 0; trial < 50; ++trial) {
    ReconSettings s = randomRecon(rng, 120, 80);
    const Mat4 m0 = randomPose(rng, trial);
    const Mat4 m1 = nextPose(rng, m0, 20.0, trial);
    const WorldBox a = pp5::gp::frameReach(m0, 120, 80, s), b = pp5::gp::frameReach(m1, 120, 80, s);
    const WorldBox grown = pp5::gp::fillInReach(m0, m1, 120, 80, s);
    s.tent.fillIn = false;
    const WorldBox u = pp5::gp::fillInReach(m0, m1, 120, 80, s);
    for (int i = 0; i < 3; ++i) {  // equal up to the relative part of the pad
      EXPECT_NEAR(u.lo[i], std::min(a.lo[i], b.lo[i]), 1e-12 + 2e-9 * std::max(std::abs(u.lo[i]), std::abs(u.hi[i])));
      EXPECT_NEAR(u.hi[i], std::max(a.hi[i], b.hi[i]), 1e-12 + 2e-9 * std::max(std::abs(u.lo[i]), std::abs(u.hi[i])));
      EXPECT_LE(grown.lo[i], u.lo[i]);
      EXPECT_GE(grown.hi[i], u.hi[i]);
    }
  }
  // A rotation beyond fill_in_max_angle_deg is a jump: no slices between.
  ReconSettings s;
  const Mat4 m0(1.0);
  Mat4 m1(1.0);
  const glm::dmat3 r = axisAngle(Vec3(0, 1, 0), 0.6);  // 34 degrees
  m1[0] = glm::dvec4(r[0], 0.0);
  m1[1] = glm::dvec4(r[1], 0.0);
  m1[2] = glm::dvec4(r[2], 0.0);
  const WorldBox a = pp5::gp::frameReach(m0, 50, 50, s), b = pp5::gp::frameReach(m1, 50, 50, s);
  const WorldBox j = pp5::gp::fillInReach(m0, m1, 50, 50, s);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(j.lo[i], std::min(a.lo[i], b.lo[i]), 1e-12 + 2e-9 * std::max(std::abs(j.lo[i]), std::abs(j.hi[i])));
    EXPECT_NEAR(j.hi[i], std::max(a.hi[i], b.hi[i]), 1e-12 + 2e-9 * std::max(std::abs(j.lo[i]), std::abs(j.hi[i])));
  }
}

// A rocking sweep about the transducer face (the image's x axis, through the
// origin): the middle slices reach deeper along world y than either frame, by
// the sagitta depth * (1 - cos(theta / 2)), so the union of the two frames'
// reaches is not enough. The box covers it, and is within 0.01 mm of the
// slices' hull plus the pad.
Mat4 rockingPose(double deg, double pixelMm) {
  const glm::dmat3 r = axisAngle(Vec3(1, 0, 0), deg * 3.14159265358979323846 / 180.0);
  return imageMatrix(Vec3(0.0), r * Vec3(pixelMm, 0, 0), r * Vec3(0, pixelMm, 0));
}

TEST(FillInReach, RockingSweepNeedsTheSagitta) {
  std::mt19937 rng(8);
  ReconSettings s;
  s.tent.kernelLateralMm = 1.0;
  s.tent.kernelAxialMm = 0.5;
  s.tent.kernelElevationMm = 0.5;
  const int w = 100, h = 241;  // 120 mm deep at 0.5 mm
  const Mat4 m0 = rockingPose(-9.0, 0.5), m1 = rockingPose(9.0, 0.5);
  const WorldBox box = pp5::gp::fillInReach(m0, m1, w, h, s);
  const WorldBox a = pp5::gp::frameReach(m0, w, h, s), b = pp5::gp::frameReach(m1, w, h, s);
  const SliceAt p0 = sliceOf(m0), p1 = sliceOf(m1);
  Hull hull;
  int outsideUnion = 0;
  for (int i = 0; i <= 128; ++i) {
    const SliceAt p = interpolate(p0, p1, i / 128.0);
    forReachPoints(rng, clippedRect(w, h, s), s, [&](double c, double r, const Vec3& k) {
      const Vec3 x = p.point(c, r, k);
      hull.add(x);
      ASSERT_TRUE(inside(box, x)) << "t " << i / 128.0 << " pixel " << c << "," << r;
      if (!inside(a, x) && !inside(b, x) && x.y > std::max(a.hi.y, b.hi.y)) ++outsideUnion;
    });
  }
  EXPECT_GT(outsideUnion, 0);
  // Deeper than the frames by about 120 (1 - cos 9 deg) = 1.48 mm.
  EXPECT_GT(hull.hi.y - std::max(a.hi.y, b.hi.y), 1.4);
  for (int i = 0; i < 3; ++i) {
    EXPECT_LE(hull.lo[i] - box.lo[i], 0.01 + padBound(box, i)) << "axis " << i;
    EXPECT_LE(box.hi[i] - hull.hi[i], 0.01 + padBound(box, i)) << "axis " << i;
  }
  // No growth along the rotation axis.
  EXPECT_NEAR(box.lo.x, std::min(a.lo.x, b.lo.x), 1e-6);
  EXPECT_NEAR(box.hi.x, std::max(a.hi.x, b.hi.x), 1e-6);
}

// The same sweep through a real tent reconstructor, with fill-in: the
// fill-in slices write voxels outside both frames' reaches, and none outside
// fillInReach.
TEST(FillInReach, ContainsEveryVoxelTheFillInWrites) {
  ReconSettings s;
  s.threads = 1;
  s.tent.kernelLateralMm = 0.5;
  s.tent.kernelAxialMm = 0.5;
  s.tent.kernelElevationMm = 0.5;
  Grid g;
  g.origin = Vec3(-2.0, -1.0, -6.5);
  g.spacing = Vec3(0.25, 0.1, 0.25);
  g.dims = Index3(37, 326, 53);
  const int w = 20, h = 121;  // 5 x 30 mm: the corners move 9.9 mm, under fill_in_max_gap_mm
  const Mat4 m0 = rockingPose(-9.5, 0.25), m1 = rockingPose(9.5, 0.25);
  auto rec = pp5::gp::makeTentReconstructor(g, s);
  pp5::Frame f;
  f.allocate(w, h, pp5::PixelType::U8);
  std::fill(f.pixels.begin(), f.pixels.end(), std::uint8_t{100});
  rec->insert(f, m0, 0.0);
  const pp5::Volume before = rec->weights();
  EXPECT_GT(rec->insert(f, m1, 0.1).fillInSlices, 10);
  const pp5::Volume after = rec->weights();
  const WorldBox box = pp5::gp::fillInReach(m0, m1, w, h, s);
  const WorldBox a = pp5::gp::frameReach(m0, w, h, s), b = pp5::gp::frameReach(m1, w, h, s);
  std::size_t changed = 0, outsideUnion = 0;
  forEachChangedVoxel(g, before, after, [&](std::int64_t i, std::int64_t j, std::int64_t k) {
    ++changed;
    const Vec3 x = g.voxelToWorld(Vec3(i, j, k));
    if (!inside(a, x) && !inside(b, x)) ++outsideUnion;
    return inside(box, x);
  });
  ASSERT_FALSE(HasFailure());
  EXPECT_GT(changed, 10000u);
  EXPECT_GT(outsideUnion, 0u);
}

// The truth: the voxels a real tent reconstructor writes lie in the reach.
TEST(FrameReach, ContainsEveryVoxelTheTentSplatWrites) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  Grid g;
  g.origin = Vec3(-12.0, -10.0, -11.0);
  g.spacing = Vec3(0.5, 0.6, 0.55);
  g.dims = Index3(49, 35, 41);
  int frames = 0, fillIns = 0;
  std::size_t changed = 0;
  for (int trial = 0; trial < 30; ++trial) {
    SCOPED_TRACE(testing::Message() << "trial " << trial);
    const int w = 40 + static_cast<int>(U(rng) * 30), h = 30 + static_cast<int>(U(rng) * 30);
    ReconSettings s = randomRecon(rng, w, h);
    s.threads = 1;
    s.tent.kernelElevationMm = 0.6 + U(rng);  // thin, so a few mm between frames fill in
    auto rec = pp5::gp::makeTentReconstructor(g, s);
    pp5::Frame f;
    f.allocate(w, h, pp5::PixelType::U8);
    for (auto& p : f.pixels) p = static_cast<std::uint8_t>(1 + U(rng) * 254);
    // A pose through the grid's middle.
    const glm::dmat3 r = randomRotation(rng);
    const double sx = 0.25 + 0.2 * U(rng), sy = 0.2 + 0.2 * U(rng), shear = trial % 3 == 2 ? 0.1 : 0.0;
    const Vec3 ex = sx * r[0], ey = shear * r[0] + sy * r[1];
    const Mat4 m0 = imageMatrix(Vec3(U(rng), U(rng), U(rng)) * 4.0 - 2.0 - 0.5 * (double(w) * ex + double(h) * ey), ex, ey);
    const Mat4 m1 = nextPose(rng, m0, 15.0, 0);
    Mat4 prev;
    for (int step = 0; step < 2; ++step) {
      const Mat4 m = step == 0 ? m0 : m1;
      const pp5::Volume before = rec->weights();
      fillIns += rec->insert(f, m, 0.1 * step).fillInSlices;
      ++frames;
      const pp5::Volume after = rec->weights();
      const WorldBox box = step == 0 ? pp5::gp::frameReach(m, w, h, s) : pp5::gp::fillInReach(prev, m, w, h, s);
      forEachChangedVoxel(g, before, after, [&](std::int64_t i, std::int64_t j, std::int64_t k) {
        ++changed;
        return inside(box, g.voxelToWorld(Vec3(i, j, k)));
      });
      ASSERT_FALSE(HasFailure());
      prev = m;
    }
  }
  EXPECT_EQ(frames, 60);
  EXPECT_GT(fillIns, 10);
  EXPECT_GT(changed, 100000u);
}

}  // namespace
