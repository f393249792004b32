// The B-mode model: speckle statistics and its correlation between slices,
// determinism, interfaces, shadows, and the display mapping.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <numbers>
#include <numeric>
#include <thread>

#include "core/error.hpp"
#include "sim/bmode.hpp"
#include "sim/probe_motion.hpp"
#include "sim/simulate.hpp"

using namespace pp5;
using namespace pp5::sim;

namespace {

constexpr double kSurface = 200.0;  // probe face height in the test phantoms

// Water over a big block of one tissue whose top is `topDepth` below the
// probe; the TGC compensates the tissue's attenuation exactly from there on.
Phantom block(Tissue t, double topDepth, const Vec3& normal = {0, 0, 1}) {
  Phantom ph;
  ph.name = "block";
  const double top = kSurface - topDepth;
  const Vec3 n = glm::normalize(normal);
  Body b;
  b.name = "block";
  b.tissue = t;
  b.distance = [top, n](const Vec3& p) {
    return sdf::intersect(glm::dot(p - Vec3(0, 0, top), n), sdf::box(p, {0, 0, top - 100}, {300, 300, 200}));
  };
  b.box = {{-300, -300, top - 300}, {300, 300, top + 100}};
  ph.add(b);
  ph.scan.surfaceZ = kSurface;
  ph.scan.tgcDbPerCmMHz = tissueProperties(t).attenuationDbPerCmMHz;
  ph.scan.tgcStartMm = topDepth;
  return ph;
}

ProbeModel shallowPaper35() {
  // The paper's probe, but only 100 mm deep (same pixel pitch), to keep tests quick.
  ProbeModel p = probePreset("paper35");
  p.depthMm = 100.0;
  p.height = 208;
  return p;
}

Mat4 poseAt(double x, double y, double surfaceZ, double thetaDeg = 0.0) {
  return armProbeToTracker({x, y, thetaDeg}, surfaceZ);  // Reference = Tracker here
}

Frame render(const BModeSimulator& sim, const Mat4& pose, std::uint64_t frameIndex = 0, BModeDebug* dbg = nullptr) {
  Frame f;
  sim.render(pose, frameIndex, f, dbg);
  return f;
}

struct Stats {
  double mean = 0, sd = 0;
  std::size_t n = 0;
};
Stats stats(const std::vector<double>& v) {
  Stats s;
  s.n = v.size();
  if (v.empty()) return s;
  s.mean = std::accumulate(v.begin(), v.end(), 0.0) / static_cast<double>(v.size());
  double ss = 0;
  for (double x : v) ss += (x - s.mean) * (x - s.mean);
  s.sd = std::sqrt(ss / static_cast<double>(v.size()));
  return s;
}

// Pixels of rows [r0, r1) and columns [c0, c1).
std::vector<double> region(const Frame& f, int r0, int r1, int c0, int c1) {
  std::vector<double> v;
  for (int r = r0; r < r1; ++r)
    for (int c = c0; c < c1; ++c) v.push_back(f.value(c, r));
  return v;
}

double correlation(const std::vector<double>& a, const std::vector<double>& b) {
  const Stats sa = stats(a), sb = stats(b);
  double cov = 0;
  for (std::size_t i = 0; i < a.size(); ++i) cov += (a[i] - sa.mean) * (b[i] - sb.mean);
  return cov / static_cast<double>(a.size()) / (sa.sd * sb.sd);
}

int rowAtDepth(const ProbeModel& p, double depthMm) { return static_cast<int>(std::lround(depthMm / p.spacingY())); }

}  // namespace

TEST(Probe, PresetsMatchThePaperAndAModernProbe) {
  const ProbeModel p = probePreset("paper35");
  EXPECT_EQ(p.width, 256);
  EXPECT_EQ(p.height, 405);
  EXPECT_DOUBLE_EQ(p.widthMm, 98.0);
  EXPECT_DOUBLE_EQ(p.depthMm, 195.0);
  EXPECT_DOUBLE_EQ(p.centerMHz, 3.5);
  const ProbeModel m = probePreset("linear75");
  EXPECT_EQ(m.width, 256);
  EXPECT_EQ(m.height, 336);
  EXPECT_DOUBLE_EQ(m.centerMHz, 7.5);
  EXPECT_LT(m.axialSigmaMm(), p.axialSigmaMm());
  EXPECT_LT(m.lateralSigmaMm(20.0), p.lateralSigmaMm(80.0));
  EXPECT_THROW(probePreset("phased12"), InputError);

  // ImageToProbe: pixel (i, j) -> lateral, depth, with the mm-per-pixel scale.
  const Mat4 m2p = p.imageToProbe();
  const Vec3 first = transformPoint(m2p, {0, 0, 0});
  const Vec3 last = transformPoint(m2p, {255, 404, 0});
  EXPECT_NEAR(first.x, -0.5 * 255 * 98.0 / 256, 1e-9);
  EXPECT_NEAR(last.x, 0.5 * 255 * 98.0 / 256, 1e-9);
  EXPECT_NEAR(first.y, 0.0, 1e-12);
  EXPECT_NEAR(last.y, 404 * 195.0 / 405, 1e-9);

  ProbeSettings s;
  s.preset = pp5::sim::ProbePreset::Linear75;
  s.widthPx = 100;
  s.depthMm = 30.0;
  const ProbeModel o = makeProbe(s);
  EXPECT_EQ(o.width, 100);
  EXPECT_EQ(o.height, 336);
  EXPECT_DOUBLE_EQ(o.depthMm, 30.0);
}

TEST(BMode, SpeckleIsRayleighAndItsMeanIsTheTruthLevel) {
  const Phantom ph = block(Tissue::Muscle, 20.0);
  const ProbeModel probe = shallowPaper35();
  const BModeSimulator sim(ph, probe, BModeSettings{}, 11);
  BModeDebug dbg;
  const Frame f = render(sim, poseAt(0, 0, kSurface), 0, &dbg);
  ASSERT_EQ(f.width, probe.width);
  ASSERT_EQ(f.height, probe.height);

  // Envelope before log compression, around the elevation focus.
  const int r0 = rowAtDepth(probe, 45.0) * dbg.oversample, r1 = rowAtDepth(probe, 90.0) * dbg.oversample;
  std::vector<double> env;
  for (int r = r0; r < r1; ++r)
    for (int c = 20; c < dbg.width - 20; ++c) env.push_back(dbg.envelope[static_cast<std::size_t>(r * dbg.width + c)]);
  const Stats e = stats(env);
  const double snr = e.mean / e.sd;
  std::printf("speckle envelope SNR %.3f (Rayleigh 1.913)\n", snr);
  EXPECT_GT(snr, 1.75) << "Rayleigh speckle has SNR 1.91";
  EXPECT_LT(snr, 2.10) << "Rayleigh speckle has SNR 1.91";
  // The RMS amplitude is the tissue's backscatter level.
  double ms = 0;
  for (double a : env) ms += a * a;
  const double rmsDb = 10.0 * std::log10(ms / static_cast<double>(env.size()));
  EXPECT_NEAR(rmsDb, tissueProperties(Tissue::Muscle).backscatterDb, 1.0);

  // Log-compressed: the mean is the truth level, and speckle keeps a spread of
  // a few dB (5.6 dB for one Rayleigh sample, less after sub-row averaging).
  const Stats p = stats(region(f, rowAtDepth(probe, 45.0), rowAtDepth(probe, 90.0), 20, f.width - 20));
  EXPECT_NEAR(p.mean, sim.displayLevel(Tissue::Muscle), 4.0);
  const double sdDb = p.sd * 60.0 / 255.0;
  std::printf("log-compressed speckle: mean %.1f (truth %.1f), sd %.2f dB\n", p.mean, sim.displayLevel(Tissue::Muscle), sdDb);
  EXPECT_GT(sdDb, 3.0);
  EXPECT_LT(sdDb, 6.0);
  // Darker tissue gives darker speckle.
  EXPECT_LT(sim.displayLevel(Tissue::Fat), sim.displayLevel(Tissue::Muscle) - 10.0);
  EXPECT_GT(sim.displayLevel(Tissue::Fascia), sim.displayLevel(Tissue::Muscle) + 20.0);
  // Water has no scatterers: it shows the electronic noise floor.
  EXPECT_EQ(sim.displayLevel(Tissue::Water), sim.noiseFloorLevel());
  EXPECT_GT(sim.noiseFloorLevel(), 0.0);
  EXPECT_LT(sim.noiseFloorLevel(), sim.displayLevel(Tissue::Fat));
}

TEST(BMode, SameSeedSameFrameOtherSeedOtherSpeckle) {
  const Phantom ph = block(Tissue::Muscle, 20.0);
  const ProbeModel probe = shallowPaper35();
  const BModeSimulator a(ph, probe, BModeSettings{}, 5), b(ph, probe, BModeSettings{}, 5), c(ph, probe, BModeSettings{}, 6);
  const Mat4 pose = poseAt(3.0, -2.0, kSurface, 10.0);
  const Frame fa = render(a, pose, 4), fb = render(b, pose, 4), fc = render(c, pose, 4);
  EXPECT_EQ(fa.pixels, fb.pixels);
  std::size_t differ = 0;
  for (std::size_t i = 0; i < fa.pixels.size(); ++i) differ += fa.pixels[i] != fc.pixels[i];
  EXPECT_GT(static_cast<double>(differ), 0.5 * static_cast<double>(fa.pixels.size()));

  // Rendering on other threads at the same time changes nothing.
  Frame t1, t2;
  std::thread th1([&] { a.render(pose, 4, t1); });
  std::thread th2([&] { a.render(poseAt(0, 0, kSurface), 9, t2); });
  th1.join();
  th2.join();
  EXPECT_EQ(t1.pixels, fa.pixels);
  EXPECT_EQ(t2.pixels, render(a, poseAt(0, 0, kSurface), 9).pixels);
}

TEST(BMode, SpeckleIsFixedInSpaceAndDecorrelatesOverTheElevationBeam) {
  const Phantom ph = block(Tissue::Muscle, 20.0);
  const ProbeModel probe = shallowPaper35();
  const BModeSimulator sim(ph, probe, BModeSettings{}, 21);
  // Near the elevation focus (70 mm) the beam is about 4 mm thick (FWHM).
  const int r0 = rowAtDepth(probe, 55.0), r1 = rowAtDepth(probe, 85.0);
  auto speckleAt = [&](double x, std::uint64_t frame) {
    return region(render(sim, poseAt(x, 0, kSurface), frame), r0, r1, 20, probe.width - 20);
  };
  const auto s0 = speckleAt(0.0, 0);
  const double near = correlation(s0, speckleAt(0.2, 1));   // different frame, so different noise
  const double far = correlation(s0, speckleAt(5.0, 2));
  EXPECT_GT(near, 0.8) << "slices 0.2 mm apart share their scatterers";
  EXPECT_LT(std::abs(far), 0.3) << "slices 5 mm apart are outside each other's beam";
  // In between, the correlation falls with distance.
  const double mid = correlation(s0, speckleAt(1.5, 3));
  std::printf("speckle correlation: 0.2 mm %.3f, 1.5 mm %.3f, 5 mm %.3f\n", near, mid, far);
  EXPECT_LT(mid, near);
  EXPECT_GT(mid, far);
}

TEST(BMode, TankBottomIsBrightWaterIsDarkWireIsADot) {
  const Phantom ph = makeDoll();
  const ProbeModel probe = probePreset("paper35");
  const BModeSimulator sim(ph, probe, BModeSettings{}, 1);
  // Beyond the doll's feet: only water, the suspension wire and the bottom.
  const Mat4 pose = poseAt(-95.0, 0.0, ph.scan.surfaceZ);
  const Frame f = render(sim, pose);
  const int bottom = rowAtDepth(probe, ph.scan.surfaceZ);  // the bottom is at z = 0
  double bestRow = 0;
  for (int r = bottom - 3; r <= bottom + 3; ++r) bestRow = std::max(bestRow, stats(region(f, r, r + 1, 0, f.width)).mean);
  const Stats water = stats(region(f, rowAtDepth(probe, 160.0), rowAtDepth(probe, 175.0), 0, f.width));
  EXPECT_GT(bestRow, 200.0);
  EXPECT_LT(water.mean, 25.0);
  // ... and its mean is the truth volume's level for water, the noise floor.
  EXPECT_NEAR(water.mean, sim.displayLevel(Tissue::Water), 1.0);
  EXPECT_GT(bestRow, water.mean + 150.0);
  const Stats nearField = stats(region(f, 5, rowAtDepth(probe, 25.0), 0, f.width));
  EXPECT_LT(nearField.mean, 25.0);

  // The wire along the tank at (y = 0, z = 150) crosses the image at right
  // angles: a bright dot at depth 30 mm in the middle column.
  const Mat4 toImage = affineInverse(pose * probe.imageToProbe());
  const Vec3 w = transformPoint(toImage, {-95.0, 0.0, 150.0});
  double peak = 0;
  for (int r = static_cast<int>(w.y) - 2; r <= static_cast<int>(w.y) + 2; ++r)
    for (int c = static_cast<int>(w.x) - 2; c <= static_cast<int>(w.x) + 2; ++c) peak = std::max(peak, f.value(c, r));
  EXPECT_GT(peak, 180.0);
  // Nothing else that bright at that depth.
  const Stats wireRow = stats(region(f, static_cast<int>(w.y) - 1, static_cast<int>(w.y) + 2, 0, 100));
  EXPECT_LT(wireRow.mean, 30.0);
}

TEST(BMode, InterfacesEchoMostWhenTheBeamMeetsThemSquarely) {
  const ProbeModel probe = shallowPaper35();
  auto peakOfInterface = [&](const Vec3& normal) {
    const Phantom ph = block(Tissue::HardPlastic, 40.0, normal);
    const BModeSimulator sim(ph, probe, BModeSettings{}, 2);
    const Frame f = render(sim, poseAt(0, 0, kSurface));
    // The interface crosses the middle columns at depth 40 mm: the mean over
    // 7 columns of each column's brightest pixel near it.
    const int c = probe.width / 2, r = rowAtDepth(probe, 40.0);
    double sum = 0;
    for (int dc = -3; dc <= 3; ++dc) {
      double peak = 0;
      for (int dr = -4; dr <= 4; ++dr) peak = std::max(peak, f.value(c + dc, r + dr));
      sum += peak;
    }
    return sum / 7.0;
  };
  const double square = peakOfInterface({0, 0, 1});
  const double tilted = peakOfInterface({0, std::sin(0.6), std::cos(0.6)});  // 34 degrees
  EXPECT_GT(square, tilted + 30.0);
}

TEST(BMode, BonesCastAcousticShadows) {
  const Phantom ph = makeForearm();
  const ProbeModel probe = probePreset("paper35");
  const BModeSimulator sim(ph, probe, BModeSettings{}, 1);
  const Mat4 pose = poseAt(0.0, 0.0, ph.scan.surfaceZ);
  const Frame f = render(sim, pose);
  const Mat4 toRef = pose * probe.imageToProbe();
  auto soft = [](Tissue t) { return t == Tissue::Muscle || t == Tissue::Fat || t == Tissue::Fascia; };

  // Columns whose beam crosses a bone, and the depth where it leaves it.
  std::vector<int> boneBottom(static_cast<std::size_t>(f.width), -1);
  std::vector<std::vector<Tissue>> label(static_cast<std::size_t>(f.width));
  for (int c = 0; c < f.width; ++c)
    for (int r = 0; r < f.height; ++r) {
      const Tissue t = ph.tissueAt(transformPoint(toRef, Vec3(c, r, 0)));
      label[static_cast<std::size_t>(c)].push_back(t);
      if (t == Tissue::Bone) boneBottom[static_cast<std::size_t>(c)] = r;
    }
  auto boneWithin = [&](int c, int margin, bool all) {
    for (int d = -margin; d <= margin; ++d) {
      const int k = std::clamp(c + d, 0, f.width - 1);
      const bool bone = boneBottom[static_cast<std::size_t>(k)] >= 0;
      if (all && !bone) return false;
      if (!all && bone) return true;
    }
    return all;
  };
  // Shadow: soft tissue below a bone, in columns well inside the bone's
  // width and rows well below it (beyond the PSF's reach).
  const int lateral = static_cast<int>(std::ceil(2.0 / probe.spacingX()));
  const int axial = static_cast<int>(std::ceil(3.0 / probe.spacingY()));
  std::vector<double> shadow, lit;
  int rMin = f.height, rMax = 0;
  for (int c = 0; c < f.width; ++c) {
    if (!boneWithin(c, lateral, true)) continue;
    for (int r = boneBottom[static_cast<std::size_t>(c)] + axial; r < f.height; ++r)
      if (soft(label[static_cast<std::size_t>(c)][static_cast<std::size_t>(r)])) {
        shadow.push_back(f.value(c, r));
        rMin = std::min(rMin, r);
        rMax = std::max(rMax, r);
      }
  }
  // Lit: soft tissue at the same depths in columns with no bone nearby.
  for (int c = 0; c < f.width; ++c)
    for (int r = rMin; r <= rMax; ++r)
      if (!boneWithin(c, 2 * lateral, false) && soft(label[static_cast<std::size_t>(c)][static_cast<std::size_t>(r)]))
        lit.push_back(f.value(c, r));
  ASSERT_GT(shadow.size(), 200u);
  ASSERT_GT(lit.size(), 200u);
  const Stats s = stats(shadow), l = stats(lit);
  EXPECT_LT(s.mean, 20.0);
  EXPECT_GT(l.mean, s.mean + 60.0);
}

TEST(BMode, AttenuationWithoutTgcDarkensWithDepth) {
  const ProbeModel probe = shallowPaper35();
  Phantom ph = block(Tissue::Muscle, 10.0);
  ph.scan.tgcDbPerCmMHz = 0.0;
  BModeSettings s;
  s.gainDb = 10.0;  // keeps the deeper speckle clear of the black clip
  const BModeSimulator sim(ph, probe, s, 3);
  const Frame f = render(sim, poseAt(0, 0, kSurface));
  const double shallow = stats(region(f, rowAtDepth(probe, 15.0), rowAtDepth(probe, 20.0), 20, 236)).mean;
  const double deep = stats(region(f, rowAtDepth(probe, 35.0), rowAtDepth(probe, 40.0), 20, 236)).mean;
  // 0.9 dB/cm/MHz at 3.5 MHz, both ways, over 2 cm: 12.6 dB, i.e. 54 grey levels at 60 dB.
  EXPECT_NEAR(shallow - deep, 12.6 * 255.0 / 60.0, 8.0);
}

TEST(BMode, LogCompressionMapsTheDynamicRange) {
  const Phantom ph = block(Tissue::Muscle, 20.0);
  BModeSettings s;
  s.dynamicRangeDb = 50.0;
  const BModeSimulator sim(ph, shallowPaper35(), s, 1);
  EXPECT_DOUBLE_EQ(sim.pixelFromAmplitude(1.0), 255.0);
  EXPECT_DOUBLE_EQ(sim.pixelFromAmplitude(std::pow(10.0, -50.0 / 20.0)), 0.0);
  EXPECT_NEAR(sim.pixelFromAmplitude(std::pow(10.0, -25.0 / 20.0)), 127.5, 1e-9);
  EXPECT_DOUBLE_EQ(sim.pixelFromAmplitude(10.0), 255.0);
  EXPECT_DOUBLE_EQ(sim.pixelFromAmplitude(0.0), 0.0);
}

// Bone under a modern probe: the cortex facing the probe is the brightest
// echo of its beam lines (soft tissue to bone is a big impedance jump), and
// what lies beyond it is in shadow.
TEST(BMode, BoneSurfaceIsTheBrightestEchoWithShadowBelow) {
  const Phantom ph = makeForearm();
  const ProbeModel probe = probePreset("linear75");
  const BModeSimulator sim(ph, probe, BModeSettings{}, 1);
  // Over the radius (centre y = 12.5), offset so the ulna stays out of view.
  const Mat4 pose = poseAt(0.0, 16.0, ph.scan.surfaceZ);
  const Frame f = render(sim, pose);
  const Mat4 toRef = pose * probe.imageToProbe();
  const double dy = probe.spacingY();

  // Per column: the true depth of the bone's top surface (-1 where the beam
  // misses the bone) and the angle between the beam and the surface normal.
  const int radius = [&] {
    for (std::size_t i = 0; i < ph.bodies.size(); ++i)
      if (ph.bodies[i].name == "arm.radius") return static_cast<int>(i);
    return -1;
  }();
  ASSERT_GE(radius, 0);
  const Vec3 beam = glm::normalize(Vec3(toRef[1]));
  std::vector<double> surface(static_cast<std::size_t>(f.width), -1.0), angleDeg(surface.size(), 90.0);
  for (int c = 0; c < f.width; ++c)
    for (double r = 0.0; r < f.height; r += 0.05) {
      const Vec3 p = transformPoint(toRef, Vec3(c, r, 0));
      if (ph.tissueAt(p) != Tissue::Bone) continue;
      surface[static_cast<std::size_t>(c)] = r * dy;
      angleDeg[static_cast<std::size_t>(c)] =
          std::acos(std::min(1.0, std::abs(glm::dot(ph.normal(radius, p), beam)))) * 180.0 / std::numbers::pi;
      break;
    }
  auto label = [&](int c, int r) { return ph.tissueAt(transformPoint(toRef, Vec3(c, r, 0))); };
  auto boneNear = [&](int c, int margin) {
    for (int d = -margin; d <= margin; ++d)
      if (surface[static_cast<std::size_t>(std::clamp(c + d, 0, f.width - 1))] >= 0.0) return true;
    return false;
  };

  // Beam lines that meet the bone within 30 degrees of its normal: per
  // column, the brightest pixel within 2 mm of the surface and the brightest
  // elsewhere; the muscle above the bone; the pixels 5-15 mm below it.
  const int window = static_cast<int>(std::lround(2.0 / dy));
  std::vector<double> peaks, muscle, shadow;
  int columns = 0, brightest = 0;
  double sMin = 1e9, sMax = -1e9;
  for (int c = 0; c < f.width; ++c) {
    const double s = surface[static_cast<std::size_t>(c)];
    if (s < 0.0 || angleDeg[static_cast<std::size_t>(c)] > 30.0) continue;
    const int rs = static_cast<int>(std::lround(s / dy));
    double peak = 0.0, elsewhere = 0.0;
    for (int r = 0; r < f.height; ++r) {
      const double v = f.value(c, r);
      if (std::abs(r - rs) <= window) {
        peak = std::max(peak, v);
      } else {
        elsewhere = std::max(elsewhere, v);
        if (r < rs && label(c, r) == Tissue::Muscle) muscle.push_back(v);
      }
    }
    ++columns;
    brightest += peak > elsewhere;
    peaks.push_back(peak);
    for (int r = rs + static_cast<int>(std::lround(5.0 / dy)); r <= rs + static_cast<int>(std::lround(15.0 / dy)) && r < f.height; ++r)
      shadow.push_back(f.value(c, r));
    sMin = std::min(sMin, s);
    sMax = std::max(sMax, s);
  }
  ASSERT_GT(columns, 20);
  // Soft tissue beside the bone (no bone within 2 mm) at the shadow's depths.
  std::vector<double> beside;
  const int lateral = static_cast<int>(std::ceil(2.0 / probe.spacingX()));
  for (int c = 0; c < f.width; ++c) {
    if (boneNear(c, lateral)) continue;
    for (int r = static_cast<int>(std::lround((sMin + 5.0) / dy)); r <= static_cast<int>(std::lround((sMax + 15.0) / dy)) && r < f.height; ++r) {
      const Tissue t = label(c, r);
      if (t == Tissue::Muscle || t == Tissue::Fat || t == Tissue::Fascia) beside.push_back(f.value(c, r));
    }
  }
  ASSERT_GT(beside.size(), 500u);
  ASSERT_GT(muscle.size(), 500u);
  const Stats sh = stats(shadow), bs = stats(beside), mu = stats(muscle), pk = stats(peaks);
  const double minPeak = *std::min_element(peaks.begin(), peaks.end());
  std::printf("bone surface: %d columns, peak mean %.1f (min %.1f) over muscle %.1f, brightest of its column in %d; "
              "5-15 mm below %.1f, beside %.1f\n",
              columns, pk.mean, minPeak, mu.mean, brightest, sh.mean, bs.mean);
  EXPECT_GE(pk.mean, mu.mean + 60.0) << "the bone surface stands out of the muscle above it";
  EXPECT_GE(minPeak, mu.mean + 40.0) << "on every beam line that meets it within 30 degrees of its normal";
  EXPECT_GE(brightest, columns * 9 / 10) << "and is the brightest echo of those beam lines";
  EXPECT_LT(sh.mean, bs.mean - 40.0) << "what lies beyond the surface is in shadow";
}

namespace {

// Mean over 24 speckle realisations (seeds) of each row of the middle
// columns, against the expected-image volume sampled at the same pixels, for
// the ideal medium. `normal` is the block's top surface: +z puts an interface
// across the axial direction, +y across the lateral one.
struct ProfileError {
  double expected = 0.0;  // RMS over rows of (measured - expected image)
  double step = 0.0;      // the same against the unblurred tissue map
};
ProfileError expectedImageProfile(const Vec3& normal, bool lateral) {
  BModeSettings bs;
  bs.medium = pp5::sim::Medium::Ideal;
  const ProbeModel probe = shallowPaper35();
  const Phantom ph = block(Tissue::Muscle, 40.0, normal);
  const Mat4 pose = poseAt(0.0, 0.0, kSurface);
  // A one-voxel-thick grid on the image plane with the pixel pitch: voxel
  // (i, j) is pixel (width-1-i, j) (the lateral axis runs along -y, depth along -z).
  const Mat4 imageToRef = pose * probe.imageToProbe();
  Grid g;
  g.spacing = Vec3(1.0, probe.spacingX(), probe.spacingY());
  g.dims = Index3(1, probe.width, probe.height);
  const Vec3 lastPixel = transformPoint(imageToRef, Vec3(probe.width - 1, probe.height - 1, 0));
  g.origin = Vec3(transformPoint(imageToRef, Vec3(0.0)).x, lastPixel.y, lastPixel.z);
  const BModeSimulator ref(ph, probe, bs, 1);
  const Volume expected = expectedImageVolume(ph, ref, g, pose, ScalarType::F32, 1);
  auto expectedAt = [&](int col, int row) {
    return expected.value(g.linear(0, probe.width - 1 - col, probe.height - 1 - row));
  };

  // Profile across the interface: rows (axial) or columns (lateral).
  const int n = lateral ? probe.width : probe.height;
  std::vector<double> sum(static_cast<std::size_t>(n), 0.0), exp(static_cast<std::size_t>(n), 0.0),
      step(static_cast<std::size_t>(n), 0.0);
  std::vector<int> count(static_cast<std::size_t>(n), 0);
  constexpr int kSeeds = 24;
  for (std::uint64_t seed = 1; seed <= kSeeds; ++seed) {
    const BModeSimulator sim(ph, probe, bs, seed);
    const Frame f = render(sim, pose, seed);
    for (int r = rowAtDepth(probe, 25.0); r < rowAtDepth(probe, 60.0); ++r)
      for (int c = 40; c < probe.width - 40; ++c) {
        const int k = lateral ? c : r;
        sum[static_cast<std::size_t>(k)] += f.value(c, r);
        ++count[static_cast<std::size_t>(k)];
        if (seed == 1) {
          exp[static_cast<std::size_t>(k)] += expectedAt(c, r);
          const Vec3 p = transformPoint(imageToRef, Vec3(c, r, 0));
          step[static_cast<std::size_t>(k)] += sim.displayLevel(ph.tissueAt(p));
        }
      }
  }
  ProfileError e;
  int used = 0;
  for (int k = 0; k < n; ++k) {
    const auto kk = static_cast<std::size_t>(k);
    if (count[kk] == 0) continue;
    const double measured = sum[kk] / count[kk];
    const double per = static_cast<double>(count[kk]) / kSeeds;
    if (std::getenv("PP5_PROFILE")) std::printf("%d %.1f %.1f %.1f\n", k, measured, exp[kk] / per, step[kk] / per);
    e.expected += std::pow(measured - exp[kk] / per, 2);
    e.step += std::pow(measured - step[kk] / per, 2);
    ++used;
  }
  e.expected = std::sqrt(e.expected / used);
  e.step = std::sqrt(e.step / used);
  std::printf("%s interface: RMS(mean of frames - expected image) %.2f, against the unblurred map %.2f\n",
              lateral ? "lateral" : "axial", e.expected, e.step);
  return e;
}

}  // namespace

TEST(BMode, ExpectedImageIsTheMeanOfTheFramesAcrossInterfaces) {
  // Depth 40 mm across the axial direction: the pulse and the pixel's
  // height blur it over about a millimetre, which the expected image
  // follows to about one level RMS (it was 4 when the blur was sampled on
  // the grid, against 10 for the unblurred map).
  const ProfileError axial = expectedImageProfile({0, 0, 1}, false);
  EXPECT_LT(axial.expected, 1.5);
  EXPECT_GT(axial.step, 5.0 * axial.expected);
  // A wall across the lateral direction (x < 0 side is tissue), blurred by the beam width.
  const ProfileError lateral = expectedImageProfile({0, 1, 0.0001}, true);
  EXPECT_LT(lateral.expected, 1.0);
  EXPECT_GT(lateral.step, 5.0 * lateral.expected) << "the beam's blur is visible, and the expected image has it";
}

TEST(BMode, ExpectedImageIsAPointValueWhateverTheGrid) {
  // A voxel holds the expected image at its centre, not an average over the
  // voxel or a blur sampled at the grid's pitch: on a 1 mm grid at any
  // offset from an interface it equals what a 0.05 mm grid gives at the same
  // points (which on a 1 mm grid a 0.2 mm pulse would not survive).
  BModeSettings bs;
  bs.medium = pp5::sim::Medium::Ideal;
  const ProbeModel probe = shallowPaper35();
  const Mat4 pose = poseAt(0.0, 0.0, kSurface);
  for (const bool lateral : {false, true}) {
    const Phantom ph = block(Tissue::Muscle, 40.0, lateral ? Vec3(0, 1, 0.0001) : Vec3(0, 0, 1));
    const BModeSimulator sim(ph, probe, bs, 1);
    // Grid axis 1 (y) is lateral, axis 2 (z) the depth; the profile runs along `axis`.
    const int axis = lateral ? 1 : 2;
    const double centre = lateral ? 0.0 : kSurface - 40.0;
    Grid fine;
    fine.spacing = Vec3(1.0);
    fine.spacing[axis] = 0.05;
    fine.dims = Index3(1, 3, 3);
    fine.dims[axis] = 241;  // 12 mm
    fine.origin = Vec3(0.0, -1.0, centre - 1.0);
    fine.origin[axis] = centre - 6.0;
    const Volume ref = expectedImageVolume(ph, sim, fine, pose, ScalarType::F32, 1);
    // Along the depth the boundary is found to 1e-6 mm and blurred in closed
    // form, so the values agree to rounding. Laterally the blur is a sum over
    // lines at most an eighth of the beam's sigma apart, which places a
    // boundary to within half that pitch (0.07 mm here): the values agree to
    // that shift along the profile's slope, steep in the log-compressed tail.
    const double shiftMm = lateral ? 0.07 : 0.0;
    double range = 0.0;
    int checked = 0;
    for (const double phase : {0.0, 0.3, 0.55, 0.8}) {
      Grid g = fine;
      g.spacing[axis] = 1.0;
      g.dims[axis] = 11;
      g.origin[axis] = centre - 5.0 + phase;
      const Volume v = expectedImageVolume(ph, sim, g, pose, ScalarType::F32, 1);
      auto refAt = [&](std::int64_t i) {
        Index3 f(0, 1, 1);
        f[axis] = i;
        return ref.value(fine.linear(f.x, f.y, f.z));
      };
      for (std::int64_t t = 0; t < 11; ++t) {
        Index3 c(0, 1, 1);
        c[axis] = t;
        const auto i = static_cast<std::int64_t>(std::lround((g.origin[axis] + static_cast<double>(t) - fine.origin[axis]) / 0.05));
        const double slope = std::max(std::abs(refAt(i + 2) - refAt(i)), std::abs(refAt(i) - refAt(i - 2))) / 0.1;  // levels per mm
        EXPECT_NEAR(v.value(g.linear(c.x, c.y, c.z)), refAt(i), 0.01 + shiftMm * slope)
            << (lateral ? "lateral" : "axial") << " at " << g.origin[axis] + static_cast<double>(t);
        range = std::max(range, std::abs(refAt(i) - refAt(0)));
        ++checked;
      }
    }
    EXPECT_EQ(checked, 44);
    EXPECT_GT(range, 20.0) << "the profile crosses the interface";
  }
}

TEST(BMode, ExpectedImageFollowsTheFramesAcrossTheElevation) {
  // The elevation beam shapes the speckle but not the tissue map (each
  // scatterer echoes with the tissue on the image plane), so a plane 0.5 mm
  // from a wall across the elevation shows the tissue on its own side: the
  // expected image has no blur along the elevation.
  BModeSettings bs;
  bs.medium = pp5::sim::Medium::Ideal;
  const ProbeModel probe = shallowPaper35();
  const Phantom ph = block(Tissue::Muscle, 40.0, {1, 0, 0.0001});  // tissue where x < 0; the elevation is +x
  const BModeSimulator ref(ph, probe, bs, 1);
  for (const double e : {-1.5, -0.5, 0.5, 1.5}) {
    const Mat4 pose = poseAt(e, 0.0, kSurface);
    std::vector<double> pixels;
    for (std::uint64_t seed = 1; seed <= 4; ++seed) {
      const BModeSimulator sim(ph, probe, bs, seed);
      const std::vector<double> r =
          region(render(sim, pose, seed), rowAtDepth(probe, 30.0), rowAtDepth(probe, 50.0), 100, 156);
      pixels.insert(pixels.end(), r.begin(), r.end());
    }
    // A grid 4 mm thick along the elevation (x), with the frame's plane in the middle.
    Grid g;
    g.spacing = Vec3(0.5, 1.0, 1.0);
    g.dims = Index3(9, 10, 20);
    g.origin = Vec3(e - 2.0, -5.0, kSurface - 50.0);  // depths 31 .. 50 mm, the same columns
    const Volume v = expectedImageVolume(ph, ref, g, pose, ScalarType::F32, 1);
    double expected = 0.0;
    for (std::int64_t k = 0; k < g.dims.z; ++k)
      for (std::int64_t j = 0; j < g.dims.y; ++j) expected += v.value(g.linear(4, j, k));
    expected /= static_cast<double>(g.dims.y * g.dims.z);
    const double want = ref.displayLevel(e < 0.0 ? Tissue::Muscle : Tissue::Water);
    EXPECT_NEAR(expected, want, 0.5) << e;
    EXPECT_NEAR(stats(pixels).mean, expected, 1.5) << e;
  }
}

TEST(BMode, ExpectedImageNeedsTheProbeAlongTheGrid) {
  const Phantom ph = block(Tissue::Muscle, 40.0);
  BModeSettings bs;
  bs.medium = pp5::sim::Medium::Ideal;
  const BModeSimulator sim(ph, shallowPaper35(), bs, 1);
  Grid g;
  g.spacing = Vec3(1.0);
  g.dims = Index3(8);
  const Mat4 turned = rotationAxisAngle(Vec3(0, 0, 1), 0.7) * poseAt(0.0, 0.0, kSurface);  // 40 degrees
  EXPECT_THROW(expectedImageVolume(ph, sim, g, turned, ScalarType::F32, 1), InputError);
  // Deep in the tissue and far up in the water the levels are the display levels.
  g.spacing = Vec3(2.0);
  g.dims = Index3(4, 4, 40);
  g.origin = Vec3(-4.0, -4.0, kSurface - 90.0);  // depths 10 .. 90 mm
  const Volume v = expectedImageVolume(ph, sim, g, poseAt(0.0, 0.0, kSurface), ScalarType::F32, 1);
  EXPECT_NEAR(v.value(g.linear(1, 1, 2)), sim.displayLevel(Tissue::Muscle), 0.01);     // depth 86 mm
  EXPECT_NEAR(v.value(g.linear(1, 1, 38)), sim.displayLevel(Tissue::Water), 0.01);     // depth 14 mm
}

