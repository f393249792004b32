// Probe motion: the 3-DOF arm's A/D and calibration, constant-interval
// capture, the sweep kinds, and the 6-DOF freehand path.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "core/error.hpp"
#include "sim/bmode.hpp"
#include "sim/probe_motion.hpp"
#include "sim/simulate.hpp"

using namespace pp5;
using namespace pp5::sim;

namespace {

Vec3 position(const Mat4& m) { return Vec3(m[3]); }

// Rotation angle (radians) of a * inverse(b).
double angleBetween(const Mat4& a, const Mat4& b) {
  const glm::dmat3 r = glm::dmat3(a) * glm::transpose(glm::dmat3(b));
  const double c = std::clamp((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0, -1.0, 1.0);
  return std::acos(c);
}

Sweep plan(const SimSettings& s) {
  const Phantom ph = makePhantom(std::string(pp5::enumName(s.phantom)));
  return planSweep(s, ph.scan, imageCornersInProbe(makeProbe(s.probe)));
}

}  // namespace

TEST(Arm, KinematicsLookDownWithElevationAlongX) {
  const Mat4 m = armProbeToTracker({10.0, 20.0, 0.0}, 180.0);
  EXPECT_TRUE(isRigid(m));
  EXPECT_NEAR(glm::length(transformVector(m, {0, 1, 0}) - Vec3(0, 0, -1)), 0.0, 1e-12);  // axial: down
  EXPECT_NEAR(glm::length(transformVector(m, {0, 0, 1}) - Vec3(1, 0, 0)), 0.0, 1e-12);   // elevation: +x
  EXPECT_NEAR(glm::length(transformVector(m, {1, 0, 0}) - Vec3(0, -1, 0)), 0.0, 1e-12);  // lateral: -y
  EXPECT_NEAR(glm::length(position(m) - Vec3(10, 20, 180)), 0.0, 1e-12);
  // Theta turns the probe about the vertical axis.
  const Mat4 t = armProbeToTracker({0.0, 0.0, 90.0}, 0.0);
  EXPECT_NEAR(glm::length(transformVector(t, {0, 0, 1}) - Vec3(0, 1, 0)), 0.0, 1e-12);
  EXPECT_NEAR(glm::length(transformVector(t, {0, 1, 0}) - Vec3(0, 0, -1)), 0.0, 1e-12);
}

TEST(Arm, AdcQuantisesToTwelveBitsAndCalibratesBack) {
  const ArmSettings s;
  const ArmAdc adc = armAdc(s);
  // Noise-free readings round-trip within half a count.
  for (const ArmPose p : {ArmPose{0.0, 0.0, 0.0}, ArmPose{123.4, 56.7, -12.3}, ArmPose{399.9, 299.9, 89.9}}) {
    const auto ideal = adc.idealCounts(p);
    const ArmPose back = adc.calibrate(ideal);
    EXPECT_NEAR(back.xMm, p.xMm, 1e-9);
    EXPECT_NEAR(back.yMm, p.yMm, 1e-9);
    EXPECT_NEAR(back.thetaDeg, p.thetaDeg, 1e-9);
    const auto c = adc.read(p, {0, 0, 0});
    const ArmPose q = adc.calibrate({double(c[0]), double(c[1]), double(c[2])});
    EXPECT_LE(std::abs(q.xMm - p.xMm), 0.5 * adc.resolution(0) + 1e-12);
    EXPECT_LE(std::abs(q.yMm - p.yMm), 0.5 * adc.resolution(1) + 1e-12);
    EXPECT_LE(std::abs(q.thetaDeg - p.thetaDeg), 0.5 * adc.resolution(2) + 1e-12);
  }
  EXPECT_NEAR(adc.resolution(0), 400.0 / 4095.0, 1e-12);
  // Straight ahead is exactly a count.
  EXPECT_EQ(adc.read({0, 0, 0}, {0, 0, 0})[2], 2048);
  EXPECT_NEAR(adc.calibrate({0, 0, 2048}).thetaDeg, 0.0, 1e-12);
  // Out of range and huge noise still give counts in 0..4095.
  const auto lo = adc.read({-50.0, -50.0, -120.0}, {-30, -30, -30});
  const auto hi = adc.read({900.0, 900.0, 120.0}, {30, 30, 30});
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(lo[static_cast<std::size_t>(i)], 0);
    EXPECT_EQ(hi[static_cast<std::size_t>(i)], ArmAdc::kMaxCount);
  }
}

TEST(Sweep, ConstantIntervalCaptureOnTheDollSweep) {
  SimSettings s;  // the default: doll, parallel pass along x, 2 mm
  const Sweep sw = plan(s);
  ASSERT_GT(sw.frames.size(), 80u);
  ASSERT_LT(sw.frames.size(), 100u);
  const Mat4 refToTracker = sw.referenceToTracker;
  EXPECT_NEAR(glm::length(position(refToTracker) - s.arm.referenceToTrackerMm), 0.0, 1e-12);
  for (std::size_t i = 0; i < sw.frames.size(); ++i) {
    const CapturedFrame& f = sw.frames[i];
    // Video frames at 30 per second.
    EXPECT_NEAR(f.timestamp * 30.0, std::round(f.timestamp * 30.0), 1e-9);
    EXPECT_NEAR(f.timestamp, static_cast<double>(f.videoFrame) / 30.0, 1e-12);
    ASSERT_TRUE(f.hasArm);
    for (int c : f.armCounts) {
      EXPECT_GE(c, 0);
      EXPECT_LE(c, ArmAdc::kMaxCount);
    }
    // The reported pose is the true one within the A/D's noise and resolution.
    EXPECT_LT(glm::length(position(f.probeToTracker) - position(f.trueProbeToTracker)), 0.6);
    if (i == 0) continue;
    const CapturedFrame& p = sw.frames[i - 1];
    EXPECT_GT(f.videoFrame, p.videoFrame);
    const double step = glm::length(position(f.trueProbeToTracker) - position(p.trueProbeToTracker));
    EXPECT_NEAR(step, s.sweep.captureIntervalMm, 0.5) << "frame " << i;
    // The rule is judged on the reported pose: never closer than the interval.
    // (judged on the image's corners, so the origin may fall short by the
    // corners' share of theta's noise)
    EXPECT_GE(glm::length(position(f.probeToTracker) - position(p.probeToTracker)), s.sweep.captureIntervalMm - 0.1);
  }
  // The sweep covers the doll along x, centred on it.
  const double x0 = position(sw.frames.front().trueProbeToTracker).x - refToTracker[3].x;
  const double x1 = position(sw.frames.back().trueProbeToTracker).x - refToTracker[3].x;
  EXPECT_NEAR(x0, -95.0, 1.0);
  EXPECT_NEAR(x1, 95.0, 2.5);
}

TEST(Sweep, OtherIntervalsAndEveryFrame) {
  for (double interval : {3.0, 5.0}) {
    SimSettings s;
    s.sweep.captureIntervalMm = interval;
    const Sweep sw = plan(s);
    for (std::size_t i = 1; i < sw.frames.size(); ++i)
      EXPECT_NEAR(glm::length(position(sw.frames[i].trueProbeToTracker) - position(sw.frames[i - 1].trueProbeToTracker)),
                  interval, 0.5);
    EXPECT_NEAR(static_cast<double>(sw.frames.size()), 190.0 / interval, 190.0 / interval * 0.15);
  }
  SimSettings s;
  s.sweep.capture = pp5::sim::Capture::EveryFrame;
  const Sweep all = plan(s);
  EXPECT_EQ(all.frames.size(), all.videoFrames);
  s.sweep.maxFrames = 7;
  EXPECT_EQ(plan(s).frames.size(), 7u);
}

TEST(Sweep, ArmReadingsAreNoisyButDeterministic) {
  SimSettings s;
  const Sweep a = plan(s), b = plan(s);
  ASSERT_EQ(a.frames.size(), b.frames.size());
  for (std::size_t i = 0; i < a.frames.size(); ++i) EXPECT_EQ(a.frames[i].armCounts, b.frames[i].armCounts);
  s.seed = 2;
  const Sweep c = plan(s);
  std::size_t differ = 0;
  for (std::size_t i = 0; i < std::min(a.frames.size(), c.frames.size()); ++i)
    differ += a.frames[i].probeToTracker != c.frames[i].probeToTracker;
  EXPECT_GT(differ, a.frames.size() / 2);
  // Without noise, the reading is the true pose quantised.
  s.arm.noiseCounts = 0.0;
  const ArmAdc adc = armAdc(s.arm);
  for (const CapturedFrame& f : plan(s).frames) {
    EXPECT_LE(std::abs(f.armReported.yMm - position(f.trueProbeToTracker).y), adc.resolution(1));
    EXPECT_LE(std::abs(f.armReported.thetaDeg), adc.resolution(2));
  }
}

TEST(Sweep, ParallelPassesSideBySide) {
  SimSettings s;
  s.sweep.passes = 3;
  s.sweep.passSpacingMm = 15.0;
  s.sweep.lengthMm = 60.0;
  const Sweep sw = plan(s);
  std::vector<double> ys[3];
  for (const CapturedFrame& f : sw.frames) ys[f.pass].push_back(position(f.trueProbeToTracker).y - sw.referenceToTracker[3].y);
  for (int k = 0; k < 3; ++k) {
    ASSERT_GT(ys[k].size(), 20u) << "pass " << k;
    for (double y : ys[k]) EXPECT_NEAR(y, (k - 1) * 15.0, 1e-9);
  }
  // No frames captured while repositioning between passes.
  for (std::size_t i = 1; i < sw.frames.size(); ++i) {
    if (sw.frames[i].pass != sw.frames[i - 1].pass) continue;
    EXPECT_LT(glm::length(position(sw.frames[i].trueProbeToTracker) - position(sw.frames[i - 1].trueProbeToTracker)),
              3.0);
  }
}

TEST(Sweep, AngledSweepTurnsTheImagePlane) {
  SimSettings s;
  s.sweep.kind = pp5::sim::SweepKind::Angled;
  s.sweep.angleDeg = 30.0;
  s.sweep.lengthMm = 100.0;
  const Sweep sw = plan(s);
  ASSERT_GT(sw.frames.size(), 40u);
  const Vec3 dir(std::cos(30.0 * std::numbers::pi / 180.0), std::sin(30.0 * std::numbers::pi / 180.0), 0.0);
  for (const CapturedFrame& f : sw.frames) {
    const Vec3 elevation = transformVector(f.trueProbeToTracker, {0, 0, 1});
    EXPECT_NEAR(glm::dot(elevation, dir), 1.0, 1e-9);
  }
  const Vec3 moved = position(sw.frames.back().trueProbeToTracker) - position(sw.frames.front().trueProbeToTracker);
  EXPECT_NEAR(glm::dot(glm::normalize(moved), dir), 1.0, 1e-6);
}

TEST(Sweep, BackAndForthRescansTheSameRegion) {
  SimSettings s;
  s.sweep.kind = pp5::sim::SweepKind::BackAndForth;
  s.sweep.repeats = 3;
  s.sweep.lengthMm = 60.0;
  const Sweep sw = plan(s);
  std::vector<const CapturedFrame*> byPass[3];
  for (const CapturedFrame& f : sw.frames) byPass[f.pass].push_back(&f);
  for (int k = 0; k < 3; ++k) ASSERT_GT(byPass[k].size(), 20u);
  // The second pass goes the other way...
  EXPECT_GT(position(byPass[0].back()->trueProbeToTracker).x, position(byPass[0].front()->trueProbeToTracker).x);
  EXPECT_LT(position(byPass[1].back()->trueProbeToTracker).x, position(byPass[1].front()->trueProbeToTracker).x);
  // ...over the same places: every frame of pass 1 lies close to one of pass 0.
  for (const CapturedFrame* f : byPass[1]) {
    double best = 1e9;
    for (const CapturedFrame* g : byPass[0])
      best = std::min(best, glm::length(position(f->trueProbeToTracker) - position(g->trueProbeToTracker)));
    EXPECT_LT(best, 1.5);
  }
  // Capture runs on across the turns: frames stay about an interval apart.
  for (std::size_t i = 1; i < sw.frames.size(); ++i) {
    const double d = glm::length(position(sw.frames[i].probeToTracker) - position(sw.frames[i - 1].probeToTracker));
    EXPECT_GE(d, s.sweep.captureIntervalMm - 0.15);
  }
}

TEST(Sweep, ArmRangeIsEnforced) {
  SimSettings s;
  s.sweep.lengthMm = 1000.0;
  EXPECT_THROW(plan(s), InputError);
}

TEST(Freehand, PathIsSmoothAndSixDof) {
  const FreehandSettings fs;
  const FreehandPath path(fs, {-50, 0, 0}, {50, 0, 0}, 180.0, 0.0, 10.0, 4);
  const double dt = 1e-3;
  double maxRate = 0, maxSpeed = 0, maxTilt = 0;
  Mat4 prev = path.probeToReference(0.0);
  for (double t = dt; t <= path.duration(); t += dt) {
    const Mat4 m = path.probeToReference(t);
    EXPECT_TRUE(isRigid(m, 1e-9));
    maxRate = std::max(maxRate, angleBetween(m, prev) / dt);
    maxSpeed = std::max(maxSpeed, glm::length(position(m) - position(prev)) / dt);
    // Tilt away from straight down.
    const Vec3 axial = transformVector(m, {0, 1, 0});
    maxTilt = std::max(maxTilt, std::acos(std::clamp(-axial.z, -1.0, 1.0)));
    EXPECT_LE(position(m).z, 180.0 + 1e-9) << "never above the water";
    prev = m;
  }
  EXPECT_LT(maxRate * 180.0 / std::numbers::pi, 60.0) << "degrees per second";
  EXPECT_LT(maxSpeed, 40.0) << "mm per second";
  EXPECT_GT(maxTilt * 180.0 / std::numbers::pi, 1.0) << "the hand tilts the probe";
  // Starts and ends where it should, and depends on the seed only.
  EXPECT_NEAR(position(path.probeToReference(0.0)).x, -50.0, 0.5);
  EXPECT_NEAR(position(path.probeToReference(path.duration())).x, 50.0, 0.5);
  const FreehandPath same(fs, {-50, 0, 0}, {50, 0, 0}, 180.0, 0.0, 10.0, 4);
  const FreehandPath other(fs, {-50, 0, 0}, {50, 0, 0}, 180.0, 0.0, 10.0, 5);
  EXPECT_EQ(same.probeToReference(3.3), path.probeToReference(3.3));
  EXPECT_NE(other.probeToReference(3.3), path.probeToReference(3.3));
}

TEST(Freehand, TrackerNoiseAndCapture) {
  SimSettings s;
  s.sweep.kind = pp5::sim::SweepKind::Freehand;
  const Sweep sw = plan(s);
  ASSERT_GT(sw.frames.size(), 50u);
  double maxErr = 0;
  for (std::size_t i = 0; i < sw.frames.size(); ++i) {
    const CapturedFrame& f = sw.frames[i];
    EXPECT_FALSE(f.hasArm);
    EXPECT_TRUE(isRigid(f.probeToTracker, 1e-9));
    maxErr = std::max(maxErr, glm::length(position(f.probeToTracker) - position(f.trueProbeToTracker)));
  }
  EXPECT_GT(maxErr, 0.0);
  EXPECT_LT(maxErr, 1.0);
  s.freehand.trackerNoiseMm = 0.0;
  s.freehand.trackerNoiseDeg = 0.0;
  for (const CapturedFrame& f : plan(s).frames) EXPECT_EQ(f.probeToTracker, f.trueProbeToTracker);
}
