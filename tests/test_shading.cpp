#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "core/camera.hpp"
#include "core/config.hpp"
#include "core/error.hpp"
#include "core/transfer_function.hpp"
#include "formats/volume_io.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/shade_buffer.hpp"
#include "rendering/shading.hpp"

namespace {

using pp5::Camera;
using pp5::Grid;
using pp5::Index3;
using pp5::TransferFunction;
using pp5::TransferFunctionSettings;
using pp5::Vec3;
using pp5::Volume;
using pp5::gp::Box3;
using pp5::gp::DirtyRegion;
using pp5::gp::ShadeBuffer;
using pp5::gp::ShadeSettings;
using pp5::gp::ShadeVoxel;

Grid makeGrid(Index3 dims, Vec3 spacing = Vec3(1.0), Vec3 origin = Vec3(-3.0, 2.0, 5.0)) {
  Grid g;
  g.dims = dims;
  g.spacing = spacing;
  g.origin = origin;
  return g;
}

Volume makeVolume(const Grid& g, const std::function<double(std::int64_t, std::int64_t, std::int64_t)>& f,
                  pp5::ScalarType type = pp5::ScalarType::F32) {
  Volume v;
  v.allocate(g, type);
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j)
      for (std::int64_t i = 0; i < g.dims.x; ++i) v.setValue(g.linear(i, j, k), f(i, j, k));
  return v;
}

Volume randomVolume(const Grid& g, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 255.0);
  return makeVolume(g, [&](auto, auto, auto) { return u(rng); });
}

// One colour and one opacity for every grey value.
TransferFunction flatTf(double r, double g, double b, double a) {
  TransferFunctionSettings s;
  s.opacity = {{0, a, 0, 0}, {255, a, 0, 0}};
  s.colour = {{0, r, g, b}, {255, r, g, b}};
  return TransferFunction(s);
}

Camera orthoCamera(const Vec3& target, const Vec3& towardsEye) {
  Camera c;
  c.projection = pp5::Projection::Orthographic;
  c.target = target;
  c.eye = target + 500.0 * glm::normalize(towardsEye);
  c.up = std::abs(glm::normalize(towardsEye).z) > 0.9 ? Vec3(0, 1, 0) : Vec3(0, 0, 1);
  return c;
}

Camera perspectiveCamera(const Vec3& eye, const Vec3& target) {
  Camera c;
  c.projection = pp5::Projection::Perspective;
  c.eye = eye;
  c.target = target;
  c.up = Vec3(0, 0, 1);
  return c;
}

ShadeBuffer shadeFull(const Volume& v, const TransferFunction& tf, const ShadeSettings& s, const Camera& cam) {
  ShadeBuffer out(v.grid);
  pp5::gp::shade(v, tf, s, cam, Box3{Index3(0), v.grid.dims}, out);
  return out;
}

bool sameBits(const ShadeBuffer& a, const ShadeBuffer& b) {
  return a.grid().voxelCount() == b.grid().voxelCount() &&
         std::equal(a.data(), a.data() + a.grid().voxelCount(), b.data());
}

// The straight colour c lit by `intensity` plus a white `highlight`, at
// opacity a, premultiplied and quantised: what a shaded voxel should hold.
ShadeVoxel expected(const glm::dvec3& c, double a, double intensity, double highlight) {
  auto q = [](double x) { return static_cast<std::uint8_t>(std::lround(std::clamp(x, 0.0, 1.0) * 255.0)); };
  const glm::dvec3 lit = glm::min(c * intensity + glm::dvec3(highlight), glm::dvec3(1.0));
  return {q(lit.r * a), q(lit.g * a), q(lit.b * a), q(a)};
}

::testing::AssertionResult near(const ShadeVoxel& got, const ShadeVoxel& want, int tol, const std::string& where) {
  const int d = std::max({std::abs(got.r - want.r), std::abs(got.g - want.g), std::abs(got.b - want.b),
                          std::abs(got.a - want.a)});
  if (d <= tol) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << where << ": got (" << int(got.r) << "," << int(got.g) << "," << int(got.b)
                                       << "," << int(got.a) << "), want (" << int(want.r) << "," << int(want.g) << ","
                                       << int(want.b) << "," << int(want.a) << ")";
}

std::string at(std::int64_t i, std::int64_t j, std::int64_t k) {
  return "voxel (" + std::to_string(i) + "," + std::to_string(j) + "," + std::to_string(k) + ")";
}

// ---- classification ----

TEST(Shading, ConstantVolumeShadesToTheTransferFunction) {
  const Grid g = makeGrid({6, 5, 4});
  const TransferFunction tf;  // the [render.tf] defaults
  const Camera cam = perspectiveCamera({40, -60, 80}, {0, 0, 0});
  for (const double value : {0.0, 45.0, 100.0, 137.3, 150.0, 255.0}) {
    const Volume vol = makeVolume(g, [&](auto, auto, auto) { return value; });
    const pp5::Rgba t = tf(static_cast<float>(value));
    for (const std::string mode : {"value", "phong"}) {
      // A flat region is lit by ambient + diffuse, which is 1 by default.
      ShadeSettings s;
      s.mode = pp5::enumFromName<pp5::gp::ShadeMode>(mode);
      const ShadeBuffer out = shadeFull(vol, tf, s, cam);
      const ShadeVoxel want = expected({t.r, t.g, t.b}, t.a, 1.0, 0.0);
      for (std::uint64_t n = 0; n < g.voxelCount(); ++n)
        ASSERT_TRUE(near(out.at(n), want, 1, mode + " value " + std::to_string(value)));
    }
    // Other coefficients scale the colour, not the opacity.
    ShadeSettings dim;
    dim.ambient = 0.2;
    dim.diffuse = 0.3;
    const ShadeBuffer out = shadeFull(vol, tf, dim, cam);
    EXPECT_TRUE(near(out.at(7), expected({t.r, t.g, t.b}, t.a, 0.5, 0.0), 1, "dim"));
  }
}

TEST(Shading, ClassificationIsContinuousInTheGreyValue) {
  // A value between two table points gets the blend of theirs, not either one.
  TransferFunctionSettings ts;
  ts.opacity = {{0, 0, 0, 0}, {100, 0, 0, 0}, {101, 1, 0, 0}, {255, 1, 0, 0}};
  ts.colour = {{0, 1, 1, 1}, {255, 1, 1, 1}};
  const TransferFunction tf(ts);
  ShadeSettings s;
  s.mode = pp5::gp::ShadeMode::Value;
  const Grid g = makeGrid({1, 1, 1});
  const Camera cam;
  for (const double v : {100.25, 100.5, 100.75}) {
    const ShadeBuffer out = shadeFull(makeVolume(g, [&](auto, auto, auto) { return v; }), tf, s, cam);
    EXPECT_EQ(out.at(0).a, std::lround((v - 100.0) * 255.0)) << v;
  }
}

// grey mode: the image value as the colour, the table's opacity, no light;
// and the grey-value shading of MIP and additive: (v, v, v, v).
TEST(Shading, GreyModeShowsTheImageValue) {
  TransferFunctionSettings ts;
  ts.opacity = {{0, 0, 0, 0}, {50, 0, 0, 0}, {150, 0.8, 0, 0}, {255, 0.8, 0, 0}};
  ts.colour = {{0, 1, 0, 0}, {255, 1, 0.2, 0}};  // red: grey mode must not use it
  const TransferFunction tf(ts);
  const Grid g = makeGrid({3, 3, 3});
  const Camera cam;
  for (const double v : {40.0, 100.0, 200.0}) {
    ShadeSettings s;
    s.mode = pp5::gp::ShadeMode::Grey;
    const Volume vol = makeVolume(g, [&](auto, auto, auto) { return v; });
    const ShadeVoxel got = shadeFull(vol, tf, s, cam).at(13);
    const double a = tf(static_cast<float>(v)).a;
    EXPECT_NEAR(got.a, a * 255.0, 0.5) << v;
    EXPECT_NEAR(got.r, v / 255.0 * a * 255.0, 0.6) << v;  // premultiplied grey
    EXPECT_EQ(got.r, got.g);
    EXPECT_EQ(got.r, got.b);
    s.greyValues = true;  // what MIP and additive shade
    const ShadeVoxel grey = shadeFull(vol, tf, s, cam).at(13);
    EXPECT_EQ(grey, (ShadeVoxel{static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v),
                                static_cast<std::uint8_t>(v)}));
  }
}

TEST(Shading, TransparentUpToIsExactAndTight) {
  // transparentUpTo(v) lets shading skip a run whose largest value is v: it
  // may say so only when every value up to v classifies to opacity 0, and
  // should say so up to the last table step below the ramp.
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    const double start = trial == 0 ? 0.0 : trial == 1 ? 254.5 : 250.0 * u(rng);
    TransferFunctionSettings ts;
    ts.colour = {{0, 1, 1, 1}, {255, 1, 1, 1}};
    if (trial == 2) {
      ts.opacity = {{0, 0, 0, 0}, {255, 0, 0, 0}};  // nothing visible at all
    } else if (start == 0.0) {
      ts.opacity = {{0, 0.5, 0, 0}, {255, 1, 0, 0}};  // visible from 0
    } else {
      ts.opacity = {{0, 0, 0, 0}, {start, 0, 0, 0}, {std::min(255.0, start + 0.5 + 5.0 * u(rng)), 0.7, 0, 0},
                    {255, 0.7, 0, 0}};
      if (ts.opacity[2][0] >= 255.0) ts.opacity.pop_back();
    }
    const TransferFunction tf(ts);
    float lastTransparent = -1.0f;  // the largest value on the grid below with transparentUpTo true
    bool firstVisibleSeen = false;
    float firstVisible = 256.0f;
    for (int i = 0; i <= 255 * 64; ++i) {
      const float v = static_cast<float>(i) / 64.0f;
      if (tf.transparentUpTo(v)) lastTransparent = v;
      if (!firstVisibleSeen && tf(v).a > 0.0f) {
        firstVisibleSeen = true;
        firstVisible = v;
      }
    }
    // Never claimed past the first visible value...
    EXPECT_LT(lastTransparent, firstVisible) << trial;
    // ... and claimed up to within two table steps (1/8 grey level) of it.
    if (trial == 2) {
      EXPECT_FALSE(firstVisibleSeen);
      EXPECT_EQ(lastTransparent, 255.0f);
    } else if (start == 0.0) {
      EXPECT_EQ(lastTransparent, -1.0f);
    } else {
      EXPECT_GE(lastTransparent, firstVisible - 2.0f / TransferFunction::kStepsPerLevel - 1.0f / 64.0f) << trial;
    }
    EXPECT_FALSE(tf.transparentUpTo(1000.0f) && firstVisibleSeen);
  }
}

// ---- Phong on a linear ramp, whose gradient is known everywhere ----

struct Ramp {
  Grid g = makeGrid({9, 8, 7}, {0.5, 1.0, 2.0});
  glm::dvec3 grad{6.0, -3.0, 2.0};  // grey levels per mm; |grad| = 7
  double sign = 1.0;
  Volume volume() const {
    return makeVolume(g, [&](std::int64_t i, std::int64_t j, std::int64_t k) {
      const glm::dvec3 mm = glm::dvec3(i, j, k) * g.spacing;
      return 128.0 + sign * (glm::dot(grad, mm) - 20.0);
    });
  }
  glm::dvec3 n() const { return sign * glm::normalize(grad); }
};

const glm::dvec3 kColour{0.4, 0.6, 0.8};
constexpr double kAlpha = 0.9;

ShadeSettings phong(double ka, double kd, double ks, double shininess) {
  ShadeSettings s;
  s.ambient = ka;
  s.diffuse = kd;
  s.specular = ks;
  s.shininess = shininess;
  return s;
}

// Expected two-sided Phong for normal n, unit L towards the light, unit H.
double intensity(const ShadeSettings& s, const glm::dvec3& n, const glm::dvec3& L) {
  return s.ambient + s.diffuse * std::abs(glm::dot(n, L));
}
double highlight(const ShadeSettings& s, const glm::dvec3& n, const glm::dvec3& L, const glm::dvec3& H) {
  const double nh = (glm::dot(n, L) < 0 ? -1.0 : 1.0) * glm::dot(n, H);
  return s.specular * std::pow(std::max(nh, 0.0), s.shininess);
}

TEST(Shading, PhongDirectionalLightOnARamp) {
  const TransferFunction tf = flatTf(kColour.r, kColour.g, kColour.b, kAlpha);
  for (const double sign : {1.0, -1.0}) {  // two-sided: the same surface seen from either side
    Ramp ramp;
    ramp.sign = sign;
    const Volume vol = ramp.volume();
    const glm::dvec3 N = glm::normalize(ramp.grad);
    // Viewer along N, light 20 degrees off it: N.H = cos 10 degrees, a strong highlight.
    const glm::dvec3 side = glm::normalize(glm::cross(N, glm::dvec3(0, 0, 1)));
    const glm::dvec3 L = std::cos(glm::radians(20.0)) * N + std::sin(glm::radians(20.0)) * side;
    const Camera cam = orthoCamera({0, 0, 0}, N);
    ShadeSettings s = phong(0.1, 0.6, 0.5, 8.0);
    s.light = pp5::gp::LightKind::Direction;
    s.lightDirection = -L;
    const glm::dvec3 H = glm::normalize(L + N);
    const double hl = highlight(s, N, L, H);
    ASSERT_GT(hl, 0.4);
    const ShadeVoxel want = expected(kColour, kAlpha, intensity(s, N, L), hl);
    const ShadeBuffer out = shadeFull(vol, tf, s, cam);
    // Every voxel, faces included: one-sided differences of a linear ramp are exact too.
    for (std::int64_t k = 0; k < ramp.g.dims.z; ++k)
      for (std::int64_t j = 0; j < ramp.g.dims.y; ++j)
        for (std::int64_t i = 0; i < ramp.g.dims.x; ++i)
          ASSERT_TRUE(near(out.at(ramp.g.linear(i, j, k)), want, 1, at(i, j, k) + " sign " + std::to_string(sign)));

    // A light behind the surface lights it the same (|N.L|), and a light
    // grazing it leaves ambient alone.
    ShadeSettings back = s;
    back.lightDirection = L;
    const ShadeBuffer outBack = shadeFull(vol, tf, back, cam);
    const double hlBack = highlight(back, N, -L, glm::normalize(-L + N));
    EXPECT_TRUE(near(outBack.at(ramp.g.linear(4, 4, 3)), expected(kColour, kAlpha, intensity(s, N, L), hlBack), 1,
                     "light behind"));
    ShadeSettings grazing = s;
    grazing.specular = 0.0;
    grazing.lightDirection = -side;
    EXPECT_TRUE(near(shadeFull(vol, tf, grazing, cam).at(ramp.g.linear(4, 4, 3)),
                     expected(kColour, kAlpha, s.ambient, 0.0), 1, "grazing light"));
  }
}

TEST(Shading, PhongLightAtTheViewerFollowsEachVoxelInPerspective) {
  const TransferFunction tf = flatTf(kColour.r, kColour.g, kColour.b, kAlpha);
  Ramp ramp;
  const Volume vol = ramp.volume();
  const glm::dvec3 N = glm::normalize(ramp.grad);
  const Vec3 centre = ramp.g.voxelToWorld(Vec3(ramp.g.dims - Index3(1)) * 0.5);
  // Close to the grid, so the direction to the eye varies a lot over it.
  const Camera persp = perspectiveCamera(centre + 12.0 * N + Vec3(0, 0, 3), centre);
  const ShadeSettings s = phong(0.2, 0.5, 0.4, 4.0);  // light = "viewer"
  const ShadeBuffer out = shadeFull(vol, tf, s, persp);
  int differFromOrtho = 0;
  const Vec3 toEyeOrtho = -persp.forward();
  for (std::int64_t k = 0; k < ramp.g.dims.z; ++k)
    for (std::int64_t j = 0; j < ramp.g.dims.y; ++j)
      for (std::int64_t i = 0; i < ramp.g.dims.x; ++i) {
        const glm::dvec3 L = glm::normalize(persp.eye - ramp.g.voxelToWorld(Vec3(i, j, k)));
        const ShadeVoxel want = expected(kColour, kAlpha, intensity(s, N, L), highlight(s, N, L, L));
        ASSERT_TRUE(near(out.at(ramp.g.linear(i, j, k)), want, 1, at(i, j, k)));
        const ShadeVoxel ortho =
            expected(kColour, kAlpha, intensity(s, N, toEyeOrtho), highlight(s, N, toEyeOrtho, toEyeOrtho));
        differFromOrtho += !near(want, ortho, 2, "");
      }
  EXPECT_GT(differFromOrtho, 50);  // the test would notice a light fixed at -forward

  // Orthographic: the viewer's light is a directional light along the view.
  Camera ortho = persp;
  ortho.projection = pp5::Projection::Orthographic;
  ShadeSettings dir = s;
  dir.light = pp5::gp::LightKind::Direction;
  dir.lightDirection = ortho.forward();
  const ShadeBuffer a = shadeFull(vol, tf, s, ortho), b = shadeFull(vol, tf, dir, ortho);
  const ShadeVoxel want = expected(kColour, kAlpha, intensity(s, N, -ortho.forward()),
                                   highlight(s, N, -ortho.forward(), -ortho.forward()));
  for (std::uint64_t n = 0; n < ramp.g.voxelCount(); ++n) {
    ASSERT_TRUE(near(a.at(n), want, 1, "ortho viewer"));
    ASSERT_TRUE(near(b.at(n), a.at(n), 1, "direction along the view"));
  }
}

TEST(Shading, PhongDirectionalLightInPerspectiveUsesTheViewPerVoxel) {
  const TransferFunction tf = flatTf(kColour.r, kColour.g, kColour.b, kAlpha);
  Ramp ramp;
  const Volume vol = ramp.volume();
  const glm::dvec3 N = glm::normalize(ramp.grad);
  const Vec3 centre = ramp.g.voxelToWorld(Vec3(ramp.g.dims - Index3(1)) * 0.5);
  const Camera persp = perspectiveCamera(centre + 15.0 * N, centre);
  ShadeSettings s = phong(0.1, 0.5, 0.6, 6.0);
  s.light = pp5::gp::LightKind::Direction;
  const glm::dvec3 L = glm::normalize(N + glm::dvec3(0.2, 0.3, -0.1));
  s.lightDirection = -L;
  const ShadeBuffer out = shadeFull(vol, tf, s, persp);
  for (std::int64_t k = 0; k < ramp.g.dims.z; ++k)
    for (std::int64_t j = 0; j < ramp.g.dims.y; ++j)
      for (std::int64_t i = 0; i < ramp.g.dims.x; ++i) {
        const glm::dvec3 V = glm::normalize(persp.eye - ramp.g.voxelToWorld(Vec3(i, j, k)));
        const ShadeVoxel want = expected(kColour, kAlpha, intensity(s, N, L), highlight(s, N, L, glm::normalize(L + V)));
        ASSERT_TRUE(near(out.at(ramp.g.linear(i, j, k)), want, 1, at(i, j, k)));
      }
}

TEST(Shading, WeakGradientsFadeToAmbientPlusDiffuse) {
  const TransferFunction tf = flatTf(kColour.r, kColour.g, kColour.b, kAlpha);
  Ramp ramp;
  const Volume vol = ramp.volume();  // |grad| = 7 grey levels per mm
  const glm::dvec3 N = glm::normalize(ramp.grad);
  const Camera cam = orthoCamera({0, 0, 0}, Vec3(0, 0, 1));
  ShadeSettings s = phong(0.1, 0.6, 0.5, 2.0);
  s.light = pp5::gp::LightKind::Direction;
  s.lightDirection = Vec3(0, 0, -1);
  const glm::dvec3 L(0, 0, 1);
  s.flatGradient = 14.0;  // w = 0.5
  const double w = 0.5;
  const double I = s.ambient + s.diffuse * (1.0 - w + w * std::abs(glm::dot(N, L)));
  const ShadeVoxel want = expected(kColour, kAlpha, I, w * highlight(s, N, L, L));
  EXPECT_TRUE(near(shadeFull(vol, tf, s, cam).at(ramp.g.linear(4, 4, 3)), want, 1, "half-faded"));
}

TEST(Shading, GradientOpacityScalesOpacityByARampOfTheMagnitude) {
  const TransferFunction tf = flatTf(kColour.r, kColour.g, kColour.b, kAlpha);
  Ramp ramp;
  const Volume vol = ramp.volume();  // |grad| = 7
  const Camera cam;
  for (const std::string mode : {"value", "phong"}) {
    ShadeSettings s;
    s.mode = pp5::enumFromName<pp5::gp::ShadeMode>(mode);
    s.gradientOpacity = true;
    s.gradientOpacityLow = 3.0;
    s.gradientOpacityWidth = 10.0;  // factor (7 - 3) / 10
    const ShadeBuffer out = shadeFull(vol, tf, s, cam);
    EXPECT_NEAR(out.at(ramp.g.linear(4, 4, 3)).a, 0.4 * kAlpha * 255.0, 0.5 + 1e-9) << mode;
    s.gradientOpacityLow = 8.0;
    EXPECT_EQ(shadeFull(vol, tf, s, cam).at(ramp.g.linear(4, 4, 3)), ShadeVoxel{}) << mode;
  }
  // A constant volume has no boundary and vanishes.
  ShadeSettings s;
  s.gradientOpacity = true;
  const ShadeBuffer flat = shadeFull(makeVolume(ramp.g, [](auto, auto, auto) { return 150.0; }), tf, s, cam);
  for (std::uint64_t n = 0; n < ramp.g.voxelCount(); ++n) ASSERT_EQ(flat.at(n), ShadeVoxel{});
}

// ---- incremental equals full ----

// Gradients of random volumes reach a few hundred grey levels per mm; the
// wide ramp keeps the opacity sensitive to them instead of saturated.
std::vector<ShadeSettings> variants() {
  std::vector<ShadeSettings> v;
  ShadeSettings s;
  v.push_back(s);  // phong, light at the viewer
  s.light = pp5::gp::LightKind::Direction;
  s.gradientOpacity = true;
  s.gradientOpacityWidth = 500.0;
  v.push_back(s);
  s = ShadeSettings{};
  s.mode = pp5::gp::ShadeMode::Value;
  v.push_back(s);
  s.gradientOpacity = true;
  s.gradientOpacityWidth = 500.0;
  v.push_back(s);
  return v;
}

std::vector<Camera> cameras(const Grid& g) {
  const Vec3 centre = g.voxelToWorld(Vec3(g.dims) * 0.5);
  Camera p = perspectiveCamera(centre + Vec3(-30, -50, 40), centre);
  Camera o = p;
  o.projection = pp5::Projection::Orthographic;
  return {p, o};
}

TEST(Shading, ReshadingAChangedBoxGrownByOneEqualsAFullReshade) {
  const Grid g = makeGrid({37, 29, 23}, {0.7, 0.8, 1.1});
  const TransferFunction tf;
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(0.0, 255.0);
  const std::vector<Box3> changes = {{{5, 7, 3}, {17, 15, 11}},   // inside
                                     {{0, 0, 20}, {10, 10, 23}},  // on three faces of the grid
                                     {{36, 3, 0}, {37, 4, 1}}};   // one voxel on a corner
  for (const ShadeSettings& s : variants())
    for (const Camera& cam : cameras(g))
      for (const Box3& change : changes) {
        Volume vol = randomVolume(g, 7);
        ShadeBuffer inc = shadeFull(vol, tf, s, cam);
        for (std::int64_t k = change.lo.z; k < change.hi.z; ++k)
          for (std::int64_t j = change.lo.y; j < change.hi.y; ++j)
            for (std::int64_t i = change.lo.x; i < change.hi.x; ++i) vol.setValue(g.linear(i, j, k), u(rng));
        ShadeBuffer noMargin = inc;
        pp5::gp::shade(vol, tf, s, cam, change.grown(1), inc);
        const ShadeBuffer full = shadeFull(vol, tf, s, cam);
        EXPECT_TRUE(sameBits(inc, full)) << pp5::enumName(s.mode) << " " << pp5::enumName(s.light);
        // Without the margin the neighbours' gradients go stale.
        pp5::gp::shade(vol, tf, s, cam, change, noMargin);
        if (s.mode == pp5::gp::ShadeMode::Phong || s.gradientOpacity) {
          EXPECT_FALSE(sameBits(noMargin, full)) << pp5::enumName(s.mode);
        }
      }
}

TEST(Shading, ReshadingADirtyRegionEqualsAFullReshade) {
  const Grid g = makeGrid({41, 30, 27}, {0.8, 0.8, 0.8});
  const TransferFunction tf;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0.0, 255.0);
  for (const int brick : {5, 8, 16})
    for (const ShadeSettings& s : variants()) {
      const Camera cam = cameras(g)[0];
      Volume vol = randomVolume(g, 3);
      ShadeBuffer inc = shadeFull(vol, tf, s, cam);
      DirtyRegion dirty(g, brick);
      const Index3 bd = dirty.brickDims();
      std::uniform_int_distribution<std::int64_t> bx(0, bd.x - 1), by(0, bd.y - 1), bz(0, bd.z - 1);
      for (int n = 0; n < 6; ++n) dirty.addBrick(bx(rng), by(rng), bz(rng));
      dirty.addBrick(bd.x - 1, bd.y - 1, bd.z - 1);  // clipped by the grid
      for (std::int64_t k = 0; k < g.dims.z; ++k)
        for (std::int64_t j = 0; j < g.dims.y; ++j)
          for (std::int64_t i = 0; i < g.dims.x; ++i)
            if (dirty.containsVoxel(i, j, k)) vol.setValue(g.linear(i, j, k), u(rng));
      pp5::gp::shade(vol, tf, s, cam, dirty, inc);
      EXPECT_TRUE(sameBits(inc, shadeFull(vol, tf, s, cam))) << "brick " << brick << " " << pp5::enumName(s.mode);
    }
}

TEST(Shading, ShadingBoxesAreTheDirtyBricksAndTheirFaceNeighboursOnce) {
  const Grid g = makeGrid({13, 11, 9});
  std::mt19937 rng(5);
  for (const int brick : {1, 2, 3, 4, 7, 16})
    for (int trial = 0; trial < 4; ++trial) {
      DirtyRegion dirty(g, brick);
      const Index3 bd = dirty.brickDims();
      std::uniform_int_distribution<std::int64_t> bx(0, bd.x - 1), by(0, bd.y - 1), bz(0, bd.z - 1);
      for (int n = 0; n < 1 + trial * 3; ++n) dirty.addBrick(bx(rng), by(rng), bz(rng));
      std::vector<int> count(g.voxelCount(), 0);
      for (const Box3& b : pp5::gp::shadingBoxes(dirty)) {
        ASSERT_FALSE(b.empty());
        ASSERT_EQ(b.intersect({Index3(0), g.dims}), b);
        for (std::int64_t k = b.lo.z; k < b.hi.z; ++k)
          for (std::int64_t j = b.lo.y; j < b.hi.y; ++j)
            for (std::int64_t i = b.lo.x; i < b.hi.x; ++i) ++count[g.linear(i, j, k)];
      }
      for (std::int64_t k = 0; k < g.dims.z; ++k)
        for (std::int64_t j = 0; j < g.dims.y; ++j)
          for (std::int64_t i = 0; i < g.dims.x; ++i) {
            const bool want = dirty.containsVoxel(i, j, k) || dirty.containsVoxel(i - 1, j, k) ||
                              dirty.containsVoxel(i + 1, j, k) || dirty.containsVoxel(i, j - 1, k) ||
                              dirty.containsVoxel(i, j + 1, k) || dirty.containsVoxel(i, j, k - 1) ||
                              dirty.containsVoxel(i, j, k + 1);
            ASSERT_EQ(count[g.linear(i, j, k)], want ? 1 : 0) << "brick " << brick << " " << at(i, j, k);
          }
    }
  EXPECT_TRUE(pp5::gp::shadingBoxes(DirtyRegion(g, 4)).empty());
  // Merging: a fully dirty grid is one box.
  DirtyRegion all(g, 4);
  all.addBox({Index3(0), g.dims});
  EXPECT_EQ(pp5::gp::shadingBoxes(all), (std::vector<Box3>{{Index3(0), g.dims}}));
}

// ---- threads ----

TEST(Shading, AnyThreadCountGivesTheSameBits) {
  const Grid g = makeGrid({48, 40, 36}, {0.6, 0.7, 0.9});
  const TransferFunction tf;
  const Volume vol = randomVolume(g, 21);
  DirtyRegion dirty(g, 8);
  dirty.addBox({{3, 3, 3}, {30, 20, 12}});
  dirty.addBrick(5, 4, 4);
  for (ShadeSettings s : variants())
    for (const Camera& cam : cameras(g)) {
      s.threads = 1;
      const ShadeBuffer ref = shadeFull(vol, tf, s, cam);
      ShadeBuffer refDirty(g);
      pp5::gp::shade(vol, tf, s, cam, dirty, refDirty);
      for (const int t : {2, 3}) {
        s.threads = t;
        EXPECT_TRUE(sameBits(shadeFull(vol, tf, s, cam), ref)) << t << " threads, " << pp5::enumName(s.mode) << " " << pp5::enumName(s.light);
        ShadeBuffer d(g);
        pp5::gp::shade(vol, tf, s, cam, dirty, d);
        EXPECT_TRUE(sameBits(d, refDirty)) << t << " threads, dirty region";
      }
    }
}

// ---- robustness ----

TEST(Shading, PremultipliedColourNeverExceedsOpacity) {
  std::mt19937 rng(99);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Grid g = makeGrid({14, 13, 12}, {0.5, 0.9, 1.3});
  const double junk[] = {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity(),
                         -std::numeric_limits<double>::infinity(), -1e30, 1e30, -7.0, 300.0};
  for (int trial = 0; trial < 24; ++trial) {
    TransferFunctionSettings ts;
    ts.opacity.clear();
    ts.colour.clear();
    double x = 0.0;
    while (x <= 255.0) {
      ts.opacity.push_back({x, u(rng), 0, 0});
      ts.colour.push_back({x, u(rng), u(rng), u(rng)});
      x += 1.0 + 80.0 * u(rng);
    }
    const TransferFunction tf(ts);
    ShadeSettings s;
    s.mode = trial % 4 == 3 ? pp5::gp::ShadeMode::Value : pp5::gp::ShadeMode::Phong;
    s.ambient = u(rng);
    s.diffuse = u(rng);
    s.specular = u(rng);
    s.shininess = 1.0 + 255.0 * u(rng);
    s.light = trial % 2 ? pp5::gp::LightKind::Viewer : pp5::gp::LightKind::Direction;
    s.lightDirection = {u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5};
    s.gradientOpacity = trial % 3 == 0;
    std::mt19937 vr(static_cast<unsigned>(trial));
    Volume vol = makeVolume(g, [&](auto, auto, auto) {
      const double r = u(vr);
      return r < 0.05 ? junk[vr() % 7] : 255.0 * u(vr);
    });
    const Camera cam = cameras(g)[trial % 2];
    const ShadeBuffer out = shadeFull(vol, tf, s, cam);
    for (std::uint64_t n = 0; n < g.voxelCount(); ++n) {
      const ShadeVoxel v = out.at(n);
      ASSERT_LE(v.r, v.a) << "trial " << trial << " voxel " << n;
      ASSERT_LE(v.g, v.a) << "trial " << trial << " voxel " << n;
      ASSERT_LE(v.b, v.a) << "trial " << trial << " voxel " << n;
    }
  }
}

TEST(Shading, IntegerVolumesShadeLikeTheSameFloatValues) {
  const Grid g = makeGrid({17, 12, 9}, {0.7, 0.7, 1.0});
  std::mt19937 rng(8);
  std::vector<double> values(g.voxelCount());
  for (auto& v : values) v = static_cast<double>(rng() % 256);
  auto fill = [&](pp5::ScalarType t) {
    return makeVolume(g, [&](std::int64_t i, std::int64_t j, std::int64_t k) { return values[g.linear(i, j, k)]; }, t);
  };
  const TransferFunction tf;
  for (const ShadeSettings& s : variants()) {
    const ShadeBuffer f = shadeFull(fill(pp5::ScalarType::F32), tf, s, cameras(g)[0]);
    EXPECT_TRUE(sameBits(shadeFull(fill(pp5::ScalarType::U8), tf, s, cameras(g)[0]), f));
    EXPECT_TRUE(sameBits(shadeFull(fill(pp5::ScalarType::U16), tf, s, cameras(g)[0]), f));
  }
}

TEST(Shading, BoxesAreClippedToTheGridAndEmptyBoxesDoNothing) {
  const Grid g = makeGrid({10, 9, 8});
  const TransferFunction tf;
  const Volume vol = randomVolume(g, 2);
  const ShadeSettings s;
  const Camera cam = cameras(g)[0];
  const ShadeBuffer full = shadeFull(vol, tf, s, cam);
  const ShadeVoxel sentinel{1, 2, 3, 200};
  auto fresh = [&] {
    ShadeBuffer b(g);
    std::fill(b.data(), b.data() + g.voxelCount(), sentinel);
    return b;
  };
  ShadeBuffer out = fresh();
  const Box3 partly{{-5, -5, -5}, {4, 100, 3}};
  pp5::gp::shade(vol, tf, s, cam, partly, out);
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j)
      for (std::int64_t i = 0; i < g.dims.x; ++i)
        ASSERT_EQ(out.at(g.linear(i, j, k)), partly.contains(i, j, k) ? full.at(g.linear(i, j, k)) : sentinel)
            << at(i, j, k);
  for (const Box3& nothing : {Box3{{3, 3, 3}, {3, 9, 9}}, Box3{{4, 4, 4}, {2, 9, 9}}, Box3{{10, 0, 0}, {20, 9, 8}},
                              Box3{{-9, -9, -9}, {0, 0, 0}}}) {
    ShadeBuffer b = fresh();
    pp5::gp::shade(vol, tf, s, cam, nothing, b);
    EXPECT_TRUE(sameBits(b, fresh()));
  }
  ShadeBuffer b = fresh();
  pp5::gp::shade(vol, tf, s, cam, DirtyRegion(g), b);
  EXPECT_TRUE(sameBits(b, fresh()));
}

TEST(Shading, RefusesMismatchedGridsAndAZeroLightDirection) {
  const Grid g = makeGrid({6, 6, 6});
  const TransferFunction tf;
  const Volume vol = randomVolume(g, 1);
  ShadeBuffer wrong(makeGrid({6, 6, 5}));
  EXPECT_THROW(pp5::gp::shade(vol, tf, ShadeSettings{}, Camera{}, Box3{Index3(0), g.dims}, wrong),
               pp5::InvariantError);
  ShadeSettings s;
  s.light = pp5::gp::LightKind::Direction;
  s.lightDirection = Vec3(0.0);
  ShadeBuffer out(g);
  EXPECT_THROW(pp5::gp::shade(vol, tf, s, Camera{}, Box3{Index3(0), g.dims}, out), pp5::InputError);
  s.light = static_cast<pp5::gp::LightKind>(9);  // not a light: settings built in code are checked
  EXPECT_THROW(pp5::gp::shade(vol, tf, s, Camera{}, Box3{Index3(0), g.dims}, out), pp5::InputError);
  // Settings built in code meet the schema's ranges too: a shininess of 0 or
  // a NaN would otherwise reach the voxel loop.
  for (const auto& bad : std::vector<std::function<void(ShadeSettings&)>>{
           [](ShadeSettings& x) { x.shininess = 0.0; },
           [](ShadeSettings& x) { x.ambient = std::numeric_limits<double>::quiet_NaN(); },
           [](ShadeSettings& x) { x.gradientOpacityWidth = 0.0; },
           [](ShadeSettings& x) { x.mode = static_cast<pp5::gp::ShadeMode>(7); }}) {
    ShadeSettings x;
    bad(x);
    EXPECT_THROW(pp5::gp::shade(vol, tf, x, Camera{}, Box3{Index3(0), g.dims}, out), pp5::InputError);
  }
  // The light direction only matters for a directional light.
  s = ShadeSettings{};
  s.lightDirection = Vec3(0.0);
  EXPECT_NO_THROW(pp5::gp::shade(vol, tf, s, Camera{}, Box3{Index3(0), g.dims}, out));
  Camera nowhere;
  nowhere.target = nowhere.eye;
  EXPECT_THROW(pp5::gp::shade(vol, tf, ShadeSettings{}, nowhere, Box3{Index3(0), g.dims}, out), pp5::InvariantError);
}

// ---- options ----

TEST(Shading, OptionsLoadWithDefaultsAndRefuseOutOfRangeValues) {
  pp5::ConfigSchema schema;
  ShadeSettings s;
  s.ambient = -1.0;
  pp5::gp::registerOptions(schema, s);
  schema.applyDefaults();
  const ShadeSettings d;
  EXPECT_EQ(s.mode, d.mode);
  EXPECT_EQ(s.ambient, d.ambient);
  EXPECT_EQ(s.diffuse, d.diffuse);
  EXPECT_EQ(s.specular, d.specular);
  EXPECT_EQ(s.shininess, d.shininess);
  EXPECT_EQ(s.light, d.light);
  EXPECT_EQ(s.lightDirection, d.lightDirection);
  EXPECT_EQ(s.flatGradient, d.flatGradient);
  EXPECT_EQ(s.gradientOpacity, d.gradientOpacity);
  EXPECT_EQ(s.gradientOpacityLow, d.gradientOpacityLow);
  EXPECT_EQ(s.gradientOpacityWidth, d.gradientOpacityWidth);
  for (const auto& e : schema.entries()) {
    EXPECT_EQ(e.key.rfind("render.shading.", 0), 0u) << e.key;
    EXPECT_FALSE(e.doc.empty()) << e.key;
  }

  schema.loadString(
      "[render.shading]\nmode = \"value\"\nlight = \"direction\"\nlight_direction = [0, 0, -1]\n"
      "shininess = 64\ngradient_opacity = true\n",
      "shade.toml");
  EXPECT_EQ(s.mode, pp5::gp::ShadeMode::Value);
  EXPECT_EQ(s.lightDirection, glm::dvec3(0, 0, -1));
  EXPECT_EQ(s.shininess, 64.0);
  EXPECT_TRUE(s.gradientOpacity);

  for (const std::string bad : {"ambient = 1.5", "specular = -0.1", "shininess = 0.5", "mode = \"toon\"",
                                "light = \"sun\"", "light_direction = [0, 0, -2]", "flat_gradient = 0",
                                "gradient_opacity_width = 0", "threads = 2"}) {
    try {
      schema.loadString("[render.shading]\n" + bad + "\n", "shade.toml");
      ADD_FAILURE() << "accepted: " << bad;
    } catch (const pp5::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("shade.toml"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
