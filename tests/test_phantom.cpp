// The analytic phantoms: tissue at known points, sizes, and the distance
// bounds the beam tracer relies on.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "core/error.hpp"
#include "sim/phantom.hpp"

using namespace pp5;
using namespace pp5::sim;

namespace {

bool isDoll(Tissue t) { return t == Tissue::Vinyl || t == Tissue::HardPlastic; }

// Extent along x of the points with doll tissue, sampled every 0.25 mm in x on
// lines through the phantom (y every 2 mm, z every 1 mm).
std::pair<double, double> dollExtentX(const Phantom& ph) {
  double lo = 1e9, hi = -1e9;
  for (double y = -40.0; y <= 40.0; y += 2.0)
    for (double z = 80.0; z <= 130.0; z += 1.0)
      for (double x = -100.0; x <= 100.0; x += 0.25)
        if (isDoll(ph.tissueAt({x, y, z}))) {
          lo = std::min(lo, x);
          hi = std::max(hi, x);
        }
  return {lo, hi};
}

// Tissue changes along a vertical line, from top to bottom.
std::vector<std::pair<double, Tissue>> transitionsDown(const Phantom& ph, double x, double y, double zTop,
                                                       double zBottom, double step = 0.05) {
  std::vector<std::pair<double, Tissue>> out;
  Tissue prev = ph.tissueAt({x, y, zTop});
  out.push_back({zTop, prev});
  for (double z = zTop; z >= zBottom; z -= step) {
    const Tissue t = ph.tissueAt({x, y, z});
    if (t != prev) out.push_back({z, t});
    prev = t;
  }
  return out;
}

}  // namespace

TEST(Phantom, DollTissueAtLandmarks) {
  const Phantom ph = makeDoll();
  EXPECT_EQ(ph.tissueAt(ph.landmark("left_eye")), Tissue::HardPlastic);
  EXPECT_EQ(ph.tissueAt(ph.landmark("right_eye")), Tissue::HardPlastic);
  EXPECT_EQ(ph.tissueAt(ph.landmark("head_cavity")), Tissue::Water);  // hollow, filled with water
  EXPECT_EQ(ph.tissueAt(ph.landmark("torso_cavity")), Tissue::Water);
  EXPECT_EQ(ph.tissueAt(ph.landmark("torso_shell")), Tissue::Vinyl);
  EXPECT_EQ(ph.tissueAt(ph.landmark("thigh")), Tissue::Vinyl);  // solid limbs
  EXPECT_EQ(ph.tissueAt(ph.landmark("nose_tip") - Vec3(0, 0, 1.0)), Tissue::Vinyl);
  EXPECT_EQ(ph.tissueAt(ph.landmark("nose_tip") + Vec3(0, 0, 1.0)), Tissue::Water);
  EXPECT_EQ(ph.tissueAt(ph.landmark("wire")), Tissue::Nylon);
  EXPECT_EQ(ph.tissueAt(ph.landmark("wire") + Vec3(0, 0, 1.0)), Tissue::Water);
  EXPECT_EQ(ph.tissueAt(ph.landmark("water")), Tissue::Water);
  EXPECT_EQ(ph.tissueAt(ph.landmark("tank_bottom")), Tissue::Glass);
  EXPECT_EQ(ph.tissueAt({0.0, 0.0, 0.5}), Tissue::Water);  // just above the bottom
  EXPECT_EQ(ph.tissueAt({0.0, 0.0, -0.5}), Tissue::Glass);
}

TEST(Phantom, DollIsAboutSixteenAndAHalfCentimetresLong) {
  const Phantom ph = makeDoll();
  const auto [lo, hi] = dollExtentX(ph);
  EXPECT_GE(hi - lo, 160.0);
  EXPECT_LE(hi - lo, 170.0);
  // Lying along x, so a sweep along x from the surface sees cross-sections,
  // and hung well clear of the tank bottom and below the probe.
  const Aabb box = ph.boundsOf("doll");
  EXPECT_GT(box.lo.z, 50.0);
  EXPECT_LT(box.hi.z, ph.scan.surfaceZ - 20.0);
  EXPECT_GE(ph.scan.sweepLengthMm, hi - lo);
}

TEST(Phantom, DollEyesAreSmallFeatures) {
  const Phantom ph = makeDoll();
  const Vec3 eye = ph.landmark("left_eye");
  double lo = 0.0, hi = 0.0;
  while (ph.tissueAt(eye + Vec3(0, lo - 0.05, 0)) == Tissue::HardPlastic) lo -= 0.05;
  while (ph.tissueAt(eye + Vec3(0, hi + 0.05, 0)) == Tissue::HardPlastic) hi += 0.05;
  EXPECT_NEAR(hi - lo, 6.0, 0.2);  // a 6 mm bead
}

TEST(Phantom, DollShellIsHollowSoBothSurfacesShow) {
  const Phantom ph = makeDoll();
  // Down through the chest: water, shell, water inside, shell, water below.
  const auto tr = transitionsDown(ph, 8.0, 0.0, 140.0, 60.0);
  ASSERT_EQ(tr.size(), 5u);
  EXPECT_EQ(tr[0].second, Tissue::Water);
  EXPECT_EQ(tr[1].second, Tissue::Vinyl);
  EXPECT_EQ(tr[2].second, Tissue::Water);
  EXPECT_EQ(tr[3].second, Tissue::Vinyl);
  EXPECT_EQ(tr[4].second, Tissue::Water);
  const double topShell = tr[1].first - tr[2].first;
  const double bottomShell = tr[3].first - tr[4].first;
  EXPECT_NEAR(topShell, 2.5, 0.3);
  EXPECT_NEAR(bottomShell, 2.5, 0.3);
}

TEST(Phantom, SuspensionWireIsThin) {
  const Phantom ph = makeDoll();
  const Vec3 w = ph.landmark("wire");
  const auto tr = transitionsDown(ph, w.x, w.y, w.z + 2.0, w.z - 2.0, 0.01);
  ASSERT_EQ(tr.size(), 3u);
  const double diameter = tr[1].first - tr[2].first;
  EXPECT_GE(diameter, 0.5);
  EXPECT_LE(diameter, 1.0);
  ASSERT_FALSE(ph.wires.empty());
}

TEST(Phantom, ForearmLayersAndBones) {
  const Phantom ph = makeForearm();
  EXPECT_EQ(ph.tissueAt(ph.landmark("radius_centre")), Tissue::Bone);
  EXPECT_EQ(ph.tissueAt(ph.landmark("ulna_centre")), Tissue::Bone);
  EXPECT_EQ(ph.tissueAt(ph.landmark("skin")), Tissue::Skin);
  EXPECT_EQ(ph.tissueAt(ph.landmark("fat")), Tissue::Fat);
  EXPECT_EQ(ph.tissueAt(ph.landmark("muscle")), Tissue::Muscle);
  EXPECT_EQ(ph.tissueAt(ph.landmark("water")), Tissue::Water);
  // Down the middle: water, skin, fat, fascia, then muscle with fascia lines.
  const auto tr = transitionsDown(ph, 0.0, 0.0, 128.0, 70.0);
  ASSERT_GE(tr.size(), 6u);
  EXPECT_EQ(tr[1].second, Tissue::Skin);
  EXPECT_EQ(tr[2].second, Tissue::Fat);
  EXPECT_NEAR(tr[1].first - tr[2].first, 1.8, 0.2);
  int fascia = 0;
  for (const auto& [z, t] : tr) fascia += t == Tissue::Fascia;
  EXPECT_GE(fascia, 3);
  // Two bones of forearm size.
  for (const char* name : {"radius_centre", "ulna_centre"}) {
    const auto b = transitionsDown(ph, 0.0, ph.landmark(name).y, 115.0, 85.0);
    double top = 0, bottom = 0;
    for (std::size_t i = 0; i + 1 < b.size(); ++i)
      if (b[i].second == Tissue::Bone) {
        top = b[i].first;
        bottom = b[i + 1].first;
      }
    EXPECT_GT(top - bottom, 10.0) << name;
    EXPECT_LT(top - bottom, 16.0) << name;
  }
}

TEST(Phantom, WirePhantomHasWiresAndSpheresOfKnownSize) {
  const Phantom ph = makeWirePhantom();
  EXPECT_EQ(ph.tissueAt(ph.landmark("wire")), Tissue::Nylon);
  EXPECT_EQ(ph.tissueAt(ph.landmark("water")), Tissue::Water);
  EXPECT_EQ(ph.wires.size(), 11u);  // three N triplets and a crossing pair
  for (const auto& [name, d] : {std::pair<const char*, double>{"sphere_3mm", 3.0}, {"sphere_5mm", 5.0},
                                {"sphere_8mm", 8.0}, {"sphere_12mm", 12.0}}) {
    const Vec3 c = ph.landmark(name);
    EXPECT_EQ(ph.tissueAt(c), Tissue::Gel) << name;
    EXPECT_EQ(ph.tissueAt(c + Vec3(0.5 * d - 0.05, 0, 0)), Tissue::Gel) << name;
    EXPECT_EQ(ph.tissueAt(c + Vec3(0.5 * d + 0.05, 0, 0)), Tissue::Water) << name;
  }
}

TEST(Phantom, UnknownNameIsAnInputError) {
  EXPECT_THROW(makePhantom("teapot"), InputError);
  EXPECT_EQ(makePhantom("doll").name, "doll");
  EXPECT_EQ(makePhantom("forearm").name, "forearm");
  EXPECT_EQ(makePhantom("wires").name, "wires");
}

// The beam tracer steps by the clearance: nothing may change within it.
TEST(Phantom, ClearanceNeverOverstatesTheDistanceToABoundary) {
  std::mt19937_64 rng(7);
  for (const Phantom& ph : {makeDoll(), makeForearm(), makeWirePhantom()}) {
    const Aabb box = ph.boundsOf(ph.name == "forearm" ? "arm" : ph.name == "doll" ? "doll" : "wires").grown(5.0);
    std::uniform_real_distribution<double> ux(box.lo.x, box.hi.x), uy(box.lo.y, box.hi.y), uz(box.lo.z, box.hi.z);
    std::normal_distribution<double> dir(0.0, 1.0);
    std::uniform_real_distribution<double> frac(0.0, 0.999);
    int checked = 0;
    for (int i = 0; i < 3000; ++i) {
      const Vec3 p(ux(rng), uy(rng), uz(rng));
      const Phantom::Sample s = ph.sample(p);
      if (!std::isfinite(s.clearance) || s.clearance < 1e-3) continue;
      for (int k = 0; k < 8; ++k) {
        const Vec3 d = glm::normalize(Vec3(dir(rng), dir(rng), dir(rng)));
        const Vec3 q = p + std::min(s.clearance, 50.0) * frac(rng) * d;
        ASSERT_EQ(ph.tissueAt(q), s.tissue) << ph.name << " at " << p.x << " " << p.y << " " << p.z;
        ++checked;
      }
    }
    EXPECT_GT(checked, 5000) << ph.name;
  }
}

TEST(Phantom, DistanceFunctionsAreExactWhereTheyShouldBe) {
  const Vec3 a(0, 0, 0), b(10, 0, 0);
  EXPECT_NEAR(sdf::sphere({3, 4, 0}, {0, 0, 0}, 2.0), 3.0, 1e-12);
  EXPECT_NEAR(sdf::capsule({5, 3, 0}, a, b, 1.0), 2.0, 1e-12);
  EXPECT_NEAR(sdf::capsule({-3, 0, 0}, a, b, 1.0), 2.0, 1e-12);
  EXPECT_NEAR(sdf::box({3, 0, 0}, {0, 0, 0}, {1, 1, 1}), 2.0, 1e-12);
  EXPECT_NEAR(sdf::box({0.5, 0, 0}, {0, 0, 0}, {1, 1, 1}), -0.5, 1e-12);
  // The ellipsoid bound: exact on the axis of the smallest radius, a lower
  // bound elsewhere, zero on the surface.
  EXPECT_NEAR(sdf::ellipsoid({0, 0, 5}, {0, 0, 0}, {4, 3, 2}), 3.0, 1e-12);
  EXPECT_NEAR(sdf::ellipsoid({4, 0, 0}, {0, 0, 0}, {4, 3, 2}), 0.0, 1e-12);
  EXPECT_LE(sdf::ellipsoid({8, 0, 0}, {0, 0, 0}, {4, 3, 2}), 4.0);
  // Round cone: outside, the distance to the union of the spheres swept
  // from (a, ra) to (b, rb), which is the shape.
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-8.0, 18.0);
  const double ra = 4.0, rb = 1.5;
  for (int i = 0; i < 500; ++i) {
    const Vec3 p(u(rng), u(rng) * 0.5, u(rng) * 0.5);
    double brute = 1e9;
    for (int k = 0; k <= 20000; ++k) {
      const double t = k / 20000.0;
      brute = std::min(brute, glm::length(p - (a + t * (b - a))) - (ra + t * (rb - ra)));
    }
    const double d = sdf::roundCone(p, a, b, ra, rb);
    if (brute > 0.0)
      EXPECT_NEAR(d, brute, 1e-3);
    else
      EXPECT_LE(d, 1e-9);
  }
}

TEST(Phantom, ReflectionCoefficients) {
  EXPECT_NEAR(reflectionCoefficient(Tissue::Water, Tissue::Glass), (13.0 - 1.48) / (13.0 + 1.48), 1e-12);
  EXPECT_NEAR(reflectionCoefficient(Tissue::Glass, Tissue::Water), -reflectionCoefficient(Tissue::Water, Tissue::Glass),
              1e-12);
  EXPECT_GT(reflectionCoefficient(Tissue::Muscle, Tissue::Bone), 0.5);
  EXPECT_LT(std::abs(reflectionCoefficient(Tissue::Fat, Tissue::Muscle)), 0.2);
  // Water has no scatterers; every tissue has some.
  EXPECT_FALSE(std::isfinite(tissueProperties(Tissue::Water).backscatterDb));
  for (int t = 1; t < kTissueCount; ++t) EXPECT_TRUE(std::isfinite(tissueProperties(static_cast<Tissue>(t)).backscatterDb));
  // Only bone has a rough surface: a thin layer under it that scatters more
  // than any tissue's bulk, but less than the mirror echo of its interface.
  const TissueProperties& bone = tissueProperties(Tissue::Bone);
  EXPECT_GT(bone.rimMm, 0.0);
  EXPECT_LT(bone.rimMm, 1.0);
  EXPECT_LT(std::pow(10.0, bone.rimBackscatterDb / 20.0), reflectionCoefficient(Tissue::Muscle, Tissue::Bone));
  for (int t = 0; t < kTissueCount; ++t) {
    const TissueProperties& p = tissueProperties(static_cast<Tissue>(t));
    if (static_cast<Tissue>(t) == Tissue::Bone) continue;
    EXPECT_EQ(p.rimMm, 0.0) << p.name;
    EXPECT_GT(bone.rimBackscatterDb, p.backscatterDb) << p.name;
  }
}
