// Hole filling (STICK, GAUSSIAN, GAUSSIAN_ACCUMULATION, NEAREST_NEIGHBOR,
// DISTANCE_WEIGHT_INVERSE) on hand-made volumes with known answers, and in the
// reconstructor: incremental filling equals one final pass, bit for bit.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "core/error.hpp"
#include "reconstruction/hole_fill.hpp"
#include "reconstruction/reconstruction.hpp"
#include "reconstruction/splat_pixel.hpp"

namespace {

using namespace pp5;
using namespace pp5::gp;

// An unfilled reconstruction: values and weights (0 = hole), F32.
struct Vol {
  Grid grid;
  Volume value, weight;
  explicit Vol(Index3 dims) {
    grid.dims = dims;
    value.allocate(grid, ScalarType::F32);
    weight.allocate(grid, ScalarType::F32);
  }
  void set(std::int64_t x, std::int64_t y, std::int64_t z, float v, float w = 1.0f) {
    const std::size_t i = grid.linear(x, y, z);
    std::memcpy(&value.bytes[4 * i], &v, 4);
    std::memcpy(&weight.bytes[4 * i], &w, 4);
  }
};

float at(const Volume& v, std::int64_t x, std::int64_t y, std::int64_t z) {
  float f;
  std::memcpy(&f, &v.bytes[4 * v.grid.linear(x, y, z)], 4);
  return f;
}

PlusHoleFillingElement stick(int length, int sticks) {
  PlusHoleFillingElement e;
  e.type = PlusHoleFillingType::Stick;
  e.stickLengthLimit = length;
  e.numberOfSticksToUse = sticks;
  return e;
}
PlusHoleFillingElement cube(PlusHoleFillingType t, int size, double ratio, double stdev = 1.0) {
  PlusHoleFillingElement e;
  e.type = t;
  e.size = size;
  e.minRatio = ratio;
  e.stdev = stdev;
  return e;
}

// ---------------------------------------------------------------------------
// STICK

// Known voxels at x = 2 (10) and x = 6 (51) on a line; holes between.
TEST(HoleFill, StickBetweenTwoKnownVoxels) {
  Vol v({10, 1, 1});
  v.set(2, 0, 0, 10);
  v.set(6, 0, 0, 51);
  // PLUS: the forward value gets weight (rvs+1)/(fwd+rvs+1), the result is
  // truncated: x=3: 0.6*10 + 0.4*51 = 26.4; x=4: 0.4*10 + 0.6*51 = 34.6;
  // x=5: 0.2*10 + 0.8*51 = 42.8.
  const Volume p = fillHoles(v.value, v.weight, {stick(9, 1)}, true);
  EXPECT_EQ(at(p, 3, 0, 0), 26.0f);
  EXPECT_EQ(at(p, 4, 0, 0), 34.0f);
  EXPECT_EQ(at(p, 5, 0, 0), 42.0f);
  // float: the linear interpolation 10 + 41 * (x - 2) / 4, not truncated.
  const Volume f = fillHoles(v.value, v.weight, {stick(9, 1)}, false);
  EXPECT_FLOAT_EQ(at(f, 3, 0, 0), 20.25f);
  EXPECT_FLOAT_EQ(at(f, 4, 0, 0), 30.5f);
  EXPECT_FLOAT_EQ(at(f, 5, 0, 0), 40.75f);
  for (const Volume* o : {&p, &f}) {
    // A stick needs a known voxel on both sides within the volume.
    for (int x : {0, 1, 7, 8, 9}) EXPECT_EQ(at(*o, x, 0, 0), 0.0f) << x;
    // Known voxels are copied.
    EXPECT_EQ(at(*o, 2, 0, 0), 10.0f);
    EXPECT_EQ(at(*o, 6, 0, 0), 51.0f);
  }
}

TEST(HoleFill, StickLongerThanTheLimitFails) {
  Vol v({10, 1, 1});
  v.set(2, 0, 0, 10);
  v.set(6, 0, 0, 51);
  // Length 4: the forward walk and the backward walk share L - 1 = 3 steps.
  for (bool plus : {true, false}) {
    const Volume o = fillHoles(v.value, v.weight, {stick(4, 1)}, plus);
    for (int x : {3, 4, 5}) EXPECT_EQ(at(o, x, 0, 0), 0.0f) << x;
    // Length 5: 3 + 1, 2 + 2 and 1 + 3 steps fit.
    const Volume o5 = fillHoles(v.value, v.weight, {stick(5, 1)}, plus);
    for (int x : {3, 4, 5}) EXPECT_NE(at(o5, x, 0, 0), 0.0f) << x;
  }
}

// The shortest stick wins; N = 2 adds the next weight class.
TEST(HoleFill, StickSelectionByWeight) {
  Vol v({5, 5, 1});
  v.set(1, 2, 0, 10);   // x stick: 1 step each way, total 3, weight 1/3
  v.set(3, 2, 0, 30);
  v.set(2, 0, 0, 100);  // y stick: 2 steps each way, total 5, weight 1/5
  v.set(2, 4, 0, 200);
  const Volume one = fillHoles(v.value, v.weight, {stick(9, 1)}, true);
  EXPECT_EQ(at(one, 2, 2, 0), 23.0f);  // trunc(10/3 + 30*2/3)
  const Volume two = fillHoles(v.value, v.weight, {stick(9, 2)}, true);
  // x: 23 (weight 1/3), y: trunc(0.4*100 + 0.6*200) = 160 (weight 1/5)
  EXPECT_EQ(at(two, 2, 2, 0), std::trunc((23.0 / 3 + 160.0 / 5) / (1.0 / 3 + 1.0 / 5)));
  const Volume twoF = fillHoles(v.value, v.weight, {stick(9, 2)}, false);
  EXPECT_NEAR(at(twoF, 2, 2, 0), (20.0 / 3 + 150.0 / 5) / (1.0 / 3 + 1.0 / 5), 1e-4);

  // Equal weights are used together even beyond N.
  Vol t({3, 3, 1});
  t.set(0, 1, 0, 10);
  t.set(2, 1, 0, 20);
  t.set(1, 0, 0, 40);
  t.set(1, 2, 0, 50);
  const Volume tie = fillHoles(t.value, t.weight, {stick(9, 1)}, false);
  EXPECT_FLOAT_EQ(at(tie, 1, 1, 0), 30.0f);  // (15 + 45) / 2
}

TEST(HoleFill, IsolatedHoleStaysZero) {
  Vol v({20, 20, 20});
  v.set(0, 0, 0, 99);
  for (bool plus : {true, false}) {
    const Volume o = fillHoles(v.value, v.weight,
                               {stick(9, 1), cube(PlusHoleFillingType::Gaussian, 5, 0.0),
                                cube(PlusHoleFillingType::NearestNeighbor, 5, 0.0)},
                               plus);
    EXPECT_EQ(at(o, 15, 15, 15), 0.0f);
    EXPECT_EQ(at(o, 0, 0, 0), 99.0f);
    EXPECT_EQ(at(o, 1, 1, 1), 99.0f);  // no stick, but the Gaussian cube reaches the corner
  }
}

// ---------------------------------------------------------------------------
// Cube kernels

TEST(HoleFill, NearestNeighbor) {
  Vol v({6, 6, 6});
  v.set(2, 2, 1, 10);
  v.set(2, 1, 2, 21);
  v.set(0, 5, 5, 90);
  // Hole (2,2,2), radius 1: the two known face neighbours.
  const Volume p = fillHoles(v.value, v.weight, {cube(PlusHoleFillingType::NearestNeighbor, 3, 0.0)}, true);
  EXPECT_EQ(at(p, 2, 2, 2), 15.0f);  // trunc(15.5)
  const Volume f = fillHoles(v.value, v.weight, {cube(PlusHoleFillingType::NearestNeighbor, 3, 0.0)}, false);
  EXPECT_EQ(at(f, 2, 2, 2), 15.5f);
  // Too few known voxels: 2/27 < 0.1.
  const Volume r = fillHoles(v.value, v.weight, {cube(PlusHoleFillingType::NearestNeighbor, 3, 0.1)}, false);
  EXPECT_EQ(at(r, 2, 2, 2), 0.0f);
  // Size 5: radius 1 holds nothing around (3,3,3), radius 2 holds both.
  const Volume s5 = fillHoles(v.value, v.weight, {cube(PlusHoleFillingType::NearestNeighbor, 5, 0.0)}, false);
  EXPECT_EQ(at(s5, 3, 3, 3), 15.5f);
  // ... and the smallest cube that holds any known voxel stops the search.
  EXPECT_EQ(at(s5, 1, 4, 4), 90.0f);
}

TEST(HoleFill, GaussianAndInverseDistance) {
  Vol v({3, 3, 3});
  const float face[4] = {10, 20, 30, 41};
  v.set(0, 1, 1, face[0], 1.0f);
  v.set(2, 1, 1, face[1], 2.0f);
  v.set(1, 0, 1, face[2], 3.0f);
  v.set(1, 2, 1, face[3], 4.0f);
  v.set(0, 0, 0, 100, 5.0f);  // a corner
  const double wf[4] = {1, 2, 3, 4};
  auto expect = [&](double kFace, double kCorner, bool byWeight) {
    double s = 0, k = 0;
    for (int i = 0; i < 4; ++i) {
      const double w = kFace * (byWeight ? wf[i] : 1.0);
      s += face[i] * w;
      k += w;
    }
    const double wc = kCorner * (byWeight ? 5.0 : 1.0);
    return (s + 100 * wc) / (k + wc);
  };
  const double sigma = 1.3;
  const double gFace = std::exp(-1 / (2 * sigma * sigma)), gCorner = std::exp(-3 / (2 * sigma * sigma));
  using T = PlusHoleFillingType;
  const Volume g = fillHoles(v.value, v.weight, {cube(T::Gaussian, 3, 0.1, sigma)}, false);
  EXPECT_NEAR(at(g, 1, 1, 1), expect(gFace, gCorner, false), 1e-4);
  const Volume gp = fillHoles(v.value, v.weight, {cube(T::Gaussian, 3, 0.1, sigma)}, true);
  EXPECT_EQ(at(gp, 1, 1, 1), std::trunc(expect(gFace, gCorner, false)));
  const Volume ga = fillHoles(v.value, v.weight, {cube(T::GaussianAccumulation, 3, 0.1, sigma)}, false);
  EXPECT_NEAR(at(ga, 1, 1, 1), expect(gFace, gCorner, true), 1e-4);
  const Volume d = fillHoles(v.value, v.weight, {cube(T::DistanceWeightInverse, 3, 0.1)}, false);
  EXPECT_NEAR(at(d, 1, 1, 1), expect(1.0, 1.0 / std::sqrt(3.0), false), 1e-4);
  // 5 of 27 known: a minimum ratio of 0.2 is not met.
  const Volume none = fillHoles(v.value, v.weight, {cube(T::Gaussian, 3, 0.2, sigma)}, false);
  EXPECT_EQ(at(none, 1, 1, 1), 0.0f);
}

// Elements are tried in order; the first that succeeds decides.
TEST(HoleFill, ElementOrder) {
  Vol v({5, 1, 1});
  v.set(0, 0, 0, 10);
  v.set(2, 0, 0, 30);
  using T = PlusHoleFillingType;
  // Nearest neighbour with ratio 0.5 fails (2 of 27), the stick fills.
  const Volume a = fillHoles(v.value, v.weight, {cube(T::NearestNeighbor, 3, 0.5), stick(9, 1)}, false);
  EXPECT_EQ(at(a, 1, 0, 0), 20.0f);
  // The stick at x = 3 fails (nothing beyond), the nearest neighbour fills.
  const Volume b = fillHoles(v.value, v.weight, {stick(9, 1), cube(T::NearestNeighbor, 3, 0.0)}, false);
  EXPECT_EQ(at(b, 3, 0, 0), 30.0f);
  EXPECT_EQ(at(b, 1, 0, 0), 20.0f);  // the stick, first in the list
}

TEST(HoleFill, BadParametersAreInputErrors) {
  using T = PlusHoleFillingType;
  EXPECT_THROW(HoleFiller({stick(0, 1)}, true), InputError);
  EXPECT_THROW(HoleFiller({stick(9, 0)}, true), InputError);
  EXPECT_THROW(HoleFiller({cube(T::Gaussian, 0, 0.5)}, true), InputError);
  EXPECT_THROW(HoleFiller({cube(T::Gaussian, 3, 0.5, 0.0)}, true), InputError);
  EXPECT_EQ(HoleFiller({stick(9, 1), cube(T::Gaussian, 7, 0.5)}, true).reach(), 8);
  EXPECT_EQ(HoleFiller({cube(T::NearestNeighbor, 7, 0.5)}, true).reach(), 3);
  EXPECT_EQ(HoleFiller::defaultElements(), std::vector<PlusHoleFillingElement>{stick(9, 1)});
}

// A hole's value depends on the unfilled volume only: visiting the holes in
// another order (here backwards, one at a time) gives the same bits.
TEST(HoleFill, OrderIndependent) {
  Vol v({12, 11, 10});
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (std::int64_t z = 0; z < 10; ++z)
    for (std::int64_t y = 0; y < 11; ++y)
      for (std::int64_t x = 0; x < 12; ++x)
        if (u(rng) < 0.3f) v.set(x, y, z, std::floor(255 * u(rng)), 0.5f + u(rng));
  using T = PlusHoleFillingType;
  const std::vector<PlusHoleFillingElement> els = {cube(T::NearestNeighbor, 3, 0.3), stick(7, 2),
                                                   cube(T::Gaussian, 5, 0.05, 1.5)};
  for (bool plus : {true, false}) {
    const Volume forward = fillHoles(v.value, v.weight, els, plus);
    const HoleFiller filler(els, plus);
    struct Src {
      const float* v;
      const float* w;
      bool known(std::size_t i) const { return w[i] != 0.0f; }
      float value(std::size_t i) const { return v[i]; }
      float weight(std::size_t i) const { return w[i]; }
    } src{reinterpret_cast<const float*>(v.value.bytes.data()), reinterpret_cast<const float*>(v.weight.bytes.data())};
    std::size_t filled = 0;
    for (std::int64_t z = 9; z >= 0; --z)
      for (std::int64_t y = 10; y >= 0; --y)
        for (std::int64_t x = 11; x >= 0; --x) {
          const std::size_t i = v.grid.linear(x, y, z);
          if (src.known(i)) continue;
          const float back = filler.fill(src, v.grid.dims, x, y, z);
          ASSERT_EQ(back, at(forward, x, y, z)) << x << "," << y << "," << z;
          filled += back != 0.0f;
        }
    EXPECT_GT(filled, 100u);
  }
}

// ---------------------------------------------------------------------------
// In the reconstructor

Mat4 pose(double angle, const Vec3& centre, double pixelMm, int w, int h) {
  const Mat4 r = rotationAxisAngle(glm::normalize(Vec3(0.3, 1.0, 0.2)), angle);
  const Vec3 ex = transformVector(r, Vec3(1, 0, 0)), ey = transformVector(r, Vec3(0, 1, 0));
  Mat4 m(1.0);
  m[0] = Vec4(ex * pixelMm, 0.0);
  m[1] = Vec4(ey * pixelMm, 0.0);
  m[2] = Vec4(glm::cross(ex, ey), 0.0);
  m[3] = Vec4(centre - ex * (pixelMm * (w - 1) / 2) - ey * (pixelMm * (h - 1) / 2), 1.0);
  return m;
}

struct Sweep {
  Grid grid;
  std::vector<Frame> frames;
  std::vector<Mat4> poses;
};

// A fan of slices a few voxels apart, so that holes open between them.
Sweep sweep() {
  Sweep s;
  s.grid.dims = {30, 28, 26};
  s.grid.spacing = Vec3(0.5);
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> px(20, 235);
  for (int k = 0; k < 6; ++k) {
    Frame f;
    f.allocate(40, 36, PixelType::U8);
    for (auto& p : f.pixels) p = static_cast<std::uint8_t>(px(rng));
    s.frames.push_back(f);
    s.poses.push_back(pose(0.25 * k - 0.6, Vec3(7.5, 7.0, 6.5), 0.3, 40, 36));
  }
  return s;
}

// The default STICK and a mixed list for every arithmetic and method; the
// single kernels for one (keeps the test short).
std::vector<std::vector<PlusHoleFillingElement>> kernelSets(bool all) {
  using T = PlusHoleFillingType;
  std::vector<std::vector<PlusHoleFillingElement>> sets = {
      {}, {cube(T::GaussianAccumulation, 3, 0.1), cube(T::DistanceWeightInverse, 5, 0.02), stick(9, 1)}};
  if (all)
    for (auto e : {stick(5, 3), cube(T::Gaussian, 5, 0.05, 1.2), cube(T::NearestNeighbor, 5, 0.0)})
      sets.push_back({e});
  return sets;
}

Volume finalPass(const Sweep& s, ReconSettings st, std::size_t frames) {
  st.pixel.fillHolesIncremental = false;
  auto r = makePixelReconstructor(s.grid, st);
  for (std::size_t k = 0; k < frames; ++k) r->insert(s.frames[k], s.poses[k], 0);
  r->finish();
  return r->output();
}

TEST(HoleFill, IncrementalEqualsFinalPassAfterEveryFrame) {
  const Sweep s = sweep();
  for (const char* ar : {"plus", "float"})
    for (const char* m : {"nearest", "trilinear"})
      for (const auto& ks : kernelSets(std::string(ar) == "float" && std::string(m) == "trilinear")) {
        ReconSettings st;
        st.arithmetic = pp5::enumFromName<pp5::gp::Arithmetic>(ar);
        st.method = pp5::enumFromName<pp5::gp::Method>(m);
        st.pixel.compounding = pp5::gp::Compounding::Mean;
        st.threads = 1 + (ks.size() % 2);
        st.pixel.fillHoles = true;
        st.pixel.fillHolesIncremental = true;
        st.pixel.holeFilling = ks;
        auto r = makePixelReconstructor(s.grid, st);
        std::size_t filled = 0;
        for (std::size_t k = 0; k < s.frames.size(); ++k) {
          const Volume before = r->output();
          const InsertResult res = r->insert(s.frames[k], s.poses[k], 0);
          const Volume& after = r->output();
          ASSERT_TRUE(after.bytes == finalPass(s, st, k + 1).bytes)
              << ar << " " << m << " kernels " << ks.size() << " frame " << k;
          // The returned region covers the refilled holes too.
          for (std::int64_t z = 0; z < s.grid.dims.z; ++z)
            for (std::int64_t y = 0; y < s.grid.dims.y; ++y)
              for (std::int64_t x = 0; x < s.grid.dims.x; ++x) {
                const std::size_t i = s.grid.linear(x, y, z);
                if (std::memcmp(&after.bytes[4 * i], &before.bytes[4 * i], 4) != 0) {
                  ASSERT_TRUE(res.dirty.containsVoxel(x, y, z)) << ar << " " << m << " frame " << k;
                }
              }
        }
        for (std::size_t i = 0; i < s.grid.voxelCount(); ++i) {
          float v;
          std::memcpy(&v, &r->output().bytes[4 * i], 4);
          filled += !r->covered(i) && v != 0.0f;
        }
        EXPECT_GT(filled, 50u) << ar << " " << m << " kernels " << ks.size();
        // finish() has nothing left to do.
        const Volume last = r->output();
        r->finish();
        EXPECT_TRUE(r->output().bytes == last.bytes);
      }
}

// Frames inserted after a final pass keep the holes near them up to date.
TEST(HoleFill, InsertAfterFinish) {
  const Sweep s = sweep();
  for (const char* ar : {"plus", "float"}) {
    ReconSettings st;
    st.arithmetic = pp5::enumFromName<pp5::gp::Arithmetic>(ar);
    st.method = pp5::gp::Method::Nearest;
    st.pixel.fillHoles = true;
    auto r = makePixelReconstructor(s.grid, st);
    for (std::size_t k = 0; k < 3; ++k) r->insert(s.frames[k], s.poses[k], 0);
    r->finish();
    EXPECT_TRUE(r->output().bytes == finalPass(s, st, 3).bytes);
    r->finish();  // idempotent
    EXPECT_TRUE(r->output().bytes == finalPass(s, st, 3).bytes);
    for (std::size_t k = 3; k < s.frames.size(); ++k) r->insert(s.frames[k], s.poses[k], 0);
    EXPECT_TRUE(r->output().bytes == finalPass(s, st, s.frames.size()).bytes) << ar;
  }
}

// No elements in the settings: STICK, length 9, one stick.
TEST(HoleFill, DefaultKernel) {
  const Sweep s = sweep();
  ReconSettings st;
  st.arithmetic = pp5::gp::Arithmetic::Plus;
  st.method = pp5::gp::Method::Trilinear;
  st.pixel.fillHoles = true;
  const Volume byDefault = finalPass(s, st, s.frames.size());
  st.pixel.holeFilling = {stick(9, 1)};
  EXPECT_TRUE(byDefault.bytes == finalPass(s, st, s.frames.size()).bytes);
  st.pixel.holeFilling = {stick(3, 1)};
  EXPECT_FALSE(byDefault.bytes == finalPass(s, st, s.frames.size()).bytes);
}

}  // namespace
