#include "sim/probe_motion.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>
#include <utility>
#include <string>

#include <fmt/format.h>

#include "core/error.hpp"
#include "sim/random.hpp"

namespace pp5::sim {

namespace {

// The hand crank is uneven: the speed varies by this fraction around its mean.
constexpr double kSpeedWobble = 0.15;
// Repositioning between parallel passes (capture off) is faster than a pass.
constexpr double kRepositionSpeedFactor = 3.0;
constexpr double kTurnDegPerS = 10.0;

// Position along a move, 0..1, for elapsed fraction tau: monotone (the
// derivative is 1 +- kSpeedWobble), exactly 0 at the start and 1 at the end.
double wobbly(double tau, int wobbles, double phase) {
  const double w = 2.0 * std::numbers::pi * wobbles;
  return tau + kSpeedWobble * (std::sin(w * tau + phase) - std::sin(phase)) / w;
}

ArmPose lerp(const ArmPose& a, const ArmPose& b, double s) {
  return {a.xMm + s * (b.xMm - a.xMm), a.yMm + s * (b.yMm - a.yMm), a.thetaDeg + s * (b.thetaDeg - a.thetaDeg)};
}

}  // namespace

// ---- kinematics and A/D ----------------------------------------------------------

ArmAdc armAdc(const ArmSettings& s) { return ArmAdc(s.xSpanMm, s.ySpanMm, s.thetaSpanDeg); }

// ---- arm trajectory -------------------------------------------------------------------

void ArmTrajectory::add(const ArmPose& from, const ArmPose& to, double speed, bool capture, int pass,
                        std::uint64_t key) {
  const double dist = std::hypot(to.xMm - from.xMm, to.yMm - from.yMm);
  const double turn = std::abs(to.thetaDeg - from.thetaDeg);
  const double span = std::max({dist / speed, turn / kTurnDegPerS, 0.1});
  Segment s;
  s.from = from;
  s.to = to;
  s.t0 = duration();
  s.t1 = s.t0 + span;
  s.capture = capture;
  s.pass = pass;
  s.wobbles = std::max(1, static_cast<int>(std::lround(span / 4.0)));
  s.wobblePhase = 2.0 * std::numbers::pi * unitFromBits(mix64(key));
  segments_.push_back(s);
}

const ArmTrajectory::Segment& ArmTrajectory::segmentAt(double t) const {
  PP5_CHECK(!segments_.empty());
  for (const Segment& s : segments_)
    if (t < s.t1) return s;
  return segments_.back();
}

ArmPose ArmTrajectory::pose(double t) const {
  const Segment& s = segmentAt(t);
  const double tau = std::clamp((t - s.t0) / (s.t1 - s.t0), 0.0, 1.0);
  return lerp(s.from, s.to, wobbly(tau, s.wobbles, s.wobblePhase));
}

// ---- freehand path ------------------------------------------------------------------------

FreehandPath::FreehandPath(const FreehandSettings& s, const Vec3& start, const Vec3& end, double surfaceZ,
                           double headingDeg, double speed, std::uint64_t seed)
    : s_(s), start_(start), end_(end), surfaceZ_(surfaceZ), headingRad_(headingDeg * kDegToRad) {
  duration_ = std::max(glm::length(end - start) / speed, 0.1);
  std::uint64_t salt = 0;
  // Slow wander: three waves of 0.05..0.3 Hz whose amplitudes add up to `peak`.
  auto slow = [&](double peak) {
    std::vector<Wave> w(3);
    double total = 0.0;
    const std::uint64_t key = mixSeed(seed, 0xF4EE0000u + salt++);
    for (std::size_t i = 0; i < w.size(); ++i) {
      const std::uint64_t h = latticeHash(key, static_cast<std::int64_t>(i), 0, 0);
      w[i] = {0.3 + unitFromBits(h), 0.05 + 0.25 * unitFromBits(h >> 16), 2.0 * std::numbers::pi * unitFromBits(h >> 32)};
      total += w[i].amp;
    }
    for (auto& x : w) x.amp *= peak / total;
    return w;
  };
  // Physiological tremor: two waves of 8..12 Hz.
  auto tremor = [&](double peak) {
    std::vector<Wave> w(2);
    const std::uint64_t key = mixSeed(seed, 0x7E3303u + salt++);
    for (std::size_t i = 0; i < w.size(); ++i) {
      const std::uint64_t h = latticeHash(key, static_cast<std::int64_t>(i), 0, 0);
      w[i] = {0.5 * peak, 8.0 + 4.0 * unitFromBits(h), 2.0 * std::numbers::pi * unitFromBits(h >> 16)};
    }
    return w;
  };
  drift_ = slow(s.driftMm);
  heave_ = slow(s.heaveMm);
  tilt_ = slow(s.tiltDeg);
  roll_ = slow(s.rollDeg);
  yaw_ = slow(s.yawDeg);
  along_ = slow(0.1 * speed);  // uneven pace; slow enough never to go backwards
  for (int i = 0; i < 3; ++i) tremor_[i] = tremor(s.tremorMm);
  for (int i = 3; i < 6; ++i) tremor_[i] = tremor(s.tremorDeg);
}

double FreehandPath::sum(const std::vector<Wave>& w, double t) {
  double v = 0.0;
  for (const Wave& x : w) v += x.amp * std::sin(2.0 * std::numbers::pi * x.freq * t + x.phase);
  return v;
}

Mat4 FreehandPath::probeToReference(double t) const {
  const double tau = std::clamp(t / duration_, 0.0, 1.0);
  const Vec3 dir = end_ - start_;
  const double len = glm::length(dir);
  const Vec3 d = len > 0.0 ? dir / len : Vec3(1, 0, 0);
  const Vec3 side(-d.y, d.x, 0.0);
  // The pace wanders but the path still starts and ends where it should.
  const double along = tau * len + (sum(along_, t) - (1.0 - tau) * sum(along_, 0.0) - tau * sum(along_, duration_));
  Vec3 p = start_ + along * d + sum(drift_, t) * side;
  // Never above the water surface: the probe must stay coupled.
  p.z = surfaceZ_ - s_.heaveMm - s_.tremorMm + sum(heave_, t);
  p += Vec3(sum(tremor_[0], t), sum(tremor_[1], t), sum(tremor_[2], t));
  const double yaw = headingRad_ + (sum(yaw_, t) + sum(tremor_[5], t)) * kDegToRad;
  const double tilt = (sum(tilt_, t) + sum(tremor_[3], t)) * kDegToRad;
  const double roll = (sum(roll_, t) + sum(tremor_[4], t)) * kDegToRad;
  return translation(p) * rotationAxisAngle(Vec3(0, 0, 1), yaw) * probeMountRotation() *
         rotationAxisAngle(Vec3(1, 0, 0), tilt) * rotationAxisAngle(Vec3(0, 0, 1), roll);
}

// ---- sweeps ----------------------------------------------------------------------------------

namespace {

struct Pass {
  Vec3 from, to;  // Reference frame, z ignored
};

// The straight passes of an arm sweep, in the Reference frame.
std::vector<Pass> armPasses(const SweepSettings& sw, const Vec3& center, const Vec3& d, const Vec3& side, double len) {
  std::vector<Pass> passes;
  const Vec3 half = 0.5 * len * d;
  if (sw.kind == SweepKind::Parallel) {
    for (int k = 0; k < sw.passes; ++k) {
      const Vec3 c = center + (k - 0.5 * (sw.passes - 1)) * sw.passSpacingMm * side;
      passes.push_back({c - half, c + half});
    }
  } else if (sw.kind == SweepKind::Angled) {
    passes.push_back({center - half, center + half});
  } else if (sw.kind == SweepKind::BackAndForth) {
    for (int k = 0; k < sw.repeats; ++k) {
      if (k % 2 == 0)
        passes.push_back({center - half, center + half});
      else
        passes.push_back({center + half, center - half});
    }
  }
  return passes;
}

void checkArmRange(const ArmAdc& adc, const ArmSettings& arm, const ArmPose& p) {
  const auto c = adc.idealCounts(p);
  const char* names[3] = {"x", "y", "theta"};
  const double values[3] = {p.xMm, p.yMm, p.thetaDeg};
  const std::string ranges[3] = {fmt::format("0..{} mm (sim.arm.x_span_mm)", arm.xSpanMm),
                                 fmt::format("0..{} mm (sim.arm.y_span_mm)", arm.ySpanMm),
                                 fmt::format("+-{} degrees (sim.arm.theta_span_deg)", 0.5 * arm.thetaSpanDeg)};
  for (int i = 0; i < 3; ++i)
    if (c[static_cast<std::size_t>(i)] < 0.0 || c[static_cast<std::size_t>(i)] > ArmAdc::kMaxCount)
      throw InputError(fmt::format(
          "sim.sweep: the sweep takes the arm to {} = {:.1f}, outside its range {}; shorten sim.sweep.length_mm "
          "or move sim.arm.reference_to_tracker_mm",
          names[i], values[i], ranges[i]));
}

// A frame's A/D reading noise: a hash of (seed, sample number, channel).
std::array<double, 3> adcNoise(std::uint64_t key, std::int64_t sample, double sigma) {
  std::array<double, 3> n{};
  for (std::size_t i = 0; i < 3; ++i)
    n[i] = sigma * gaussianFromHash(latticeHash(key, sample, static_cast<std::int64_t>(i), 0));
  return n;
}

// The video frames of a sweep `duration` s long at the sweep's frame rate,
// each read by frameAt(k, t): its reported and true poses (and the arm's
// counts), or nothing where the capture switch is off (the next pass then
// starts afresh). A frame is kept when the probe has moved
// sweep.capture_interval_mm since the last kept one (or every frame).
template <class FrameAt>
Sweep captureFrames(const SimSettings& s, double duration, const Mat4& refToTracker, const std::vector<Vec3>& corners,
                    FrameAt&& frameAt) {
  Sweep sweep;
  sweep.referenceToTracker = refToTracker;
  sweep.duration = duration;
  const double fps = s.sweep.frameRateHz;
  sweep.videoFrames = static_cast<std::uint64_t>(std::floor(sweep.duration * fps)) + 1;
  std::optional<Mat4> last;
  for (std::uint64_t k = 0; k < sweep.videoFrames; ++k) {
    const double t = static_cast<double>(k) / fps;
    std::optional<CapturedFrame> f = frameAt(k, t);
    if (!f) {
      last.reset();
      continue;
    }
    const bool capture = s.sweep.capture == Capture::EveryFrame || !last ||
                         largestDisplacement(*last, f->probeToTracker, corners) >= s.sweep.captureIntervalMm;
    if (!capture) continue;
    f->videoFrame = k;
    f->timestamp = t;
    sweep.frames.push_back(*f);
    last = f->probeToTracker;
    if (s.sweep.maxFrames > 0 && static_cast<int>(sweep.frames.size()) >= s.sweep.maxFrames) break;
  }
  return sweep;
}

Sweep captureArmSweep(const SimSettings& s, const ArmTrajectory& traj, double probeZ, const Mat4& refToTracker,
                      const std::vector<Vec3>& corners) {
  const ArmAdc adc = armAdc(s.arm);
  const std::uint64_t noiseKey = mixSeed(s.seed, 0xADC0u);
  const double rate = s.arm.sampleRateHz;
  auto reading = [&](std::int64_t n) {
    return adc.read(traj.pose(static_cast<double>(n) / rate), adcNoise(noiseKey, n, s.arm.noiseCounts));
  };
  return captureFrames(s, traj.duration(), refToTracker, corners, [&](std::uint64_t, double t) {
    std::optional<CapturedFrame> f;
    const ArmTrajectory::Segment& seg = traj.segmentAt(t);
    if (!seg.capture) return f;
    // The two A/D readings around t, interpolated to the frame's time.
    const double x = t * rate;
    const auto n0 = static_cast<std::int64_t>(std::floor(x));
    const double frac = x - static_cast<double>(n0);
    const auto c0 = reading(n0), c1 = reading(n0 + 1);
    std::array<double, 3> counts{};
    for (std::size_t i = 0; i < 3; ++i) counts[i] = c0[i] + frac * (c1[i] - c0[i]);
    f.emplace();
    f->armReported = adc.calibrate(counts);
    f->probeToTracker = armProbeToTracker(f->armReported, probeZ);
    f->pass = seg.pass;
    f->trueProbeToTracker = armProbeToTracker(traj.pose(t), probeZ);
    f->hasArm = true;
    f->armCounts = frac < 0.5 ? c0 : c1;
    return f;
  });
}

// A tracker's reading: the true pose with a small random rotation (random
// axis) and translation, hashed from (seed, video frame).
Mat4 trackerReading(const Mat4& truth, const FreehandSettings& f, std::uint64_t key, std::uint64_t frame) {
  const auto k = static_cast<std::int64_t>(frame);
  Vec3 axis(gaussianFromHash(latticeHash(key, k, 0, 0)), gaussianFromHash(latticeHash(key, k, 1, 0)),
            gaussianFromHash(latticeHash(key, k, 2, 0)));
  const double len = glm::length(axis);
  axis = len > 0.0 ? axis / len : Vec3(0, 0, 1);
  const double angle = f.trackerNoiseDeg * kDegToRad * gaussianFromHash(latticeHash(key, k, 3, 0));
  const Vec3 shift(f.trackerNoiseMm * gaussianFromHash(latticeHash(key, k, 4, 0)),
                   f.trackerNoiseMm * gaussianFromHash(latticeHash(key, k, 5, 0)),
                   f.trackerNoiseMm * gaussianFromHash(latticeHash(key, k, 6, 0)));
  const Vec3 origin(truth[3]);
  // Rotate about the probe's own origin, then shift.
  return translation(origin + shift) * rotationAxisAngle(axis, angle) * translation(-origin) * truth;
}

Sweep captureFreehandSweep(const SimSettings& s, const FreehandPath& path, const Mat4& refToTracker,
                           const std::vector<Vec3>& corners) {
  const std::uint64_t key = mixSeed(s.seed, 0x7EAC3Eu);
  return captureFrames(s, path.duration(), refToTracker, corners, [&](std::uint64_t k, double t) {
    std::optional<CapturedFrame> f(std::in_place);
    f->trueProbeToTracker = refToTracker * path.probeToReference(t);
    f->probeToTracker = trackerReading(f->trueProbeToTracker, s.freehand, key, k);
    return f;
  });
}

}  // namespace

Sweep planSweep(const SimSettings& s, const ScanSetup& scan, const std::vector<Vec3>& imageCorners) {
  const SweepSettings& sw = s.sweep;
  const double len = sw.lengthMm > 0.0 ? sw.lengthMm : scan.sweepLengthMm;
  const double heading = sw.kind == SweepKind::Angled ? sw.angleDeg : 0.0;
  const Vec3 d(std::cos(heading * kDegToRad), std::sin(heading * kDegToRad), 0.0);
  const Vec3 side(-d.y, d.x, 0.0);
  const Vec3 center = Vec3(scan.sweepCenter.x, scan.sweepCenter.y, 0.0) + sw.lateralOffsetMm * side;
  const Vec3 offset = s.arm.referenceToTrackerMm;
  const Mat4 refToTracker = translation(offset);

  if (sw.kind == SweepKind::Freehand) {
    const FreehandPath path(s.freehand, center - 0.5 * len * d, center + 0.5 * len * d, scan.surfaceZ, heading,
                            sw.speedMmPerS, s.seed);
    return captureFreehandSweep(s, path, refToTracker, imageCorners);
  }
  checkedEnum(sw.kind);

  const ArmAdc adc = armAdc(s.arm);
  auto toArm = [&](const Vec3& p) { return ArmPose{p.x + offset.x, p.y + offset.y, heading}; };
  ArmTrajectory traj;
  const std::uint64_t key = mixSeed(s.seed, 0xA53u);
  const auto passes = armPasses(sw, center, d, side, len);
  for (std::size_t k = 0; k < passes.size(); ++k) {
    const ArmPose a = toArm(passes[k].from), b = toArm(passes[k].to);
    checkArmRange(adc, s.arm, a);
    checkArmRange(adc, s.arm, b);
    if (k > 0) {
      const ArmPose prev = traj.segments().back().to;
      const bool contiguous = std::hypot(prev.xMm - a.xMm, prev.yMm - a.yMm) < 1e-9;
      if (!contiguous)
        traj.add(prev, a, kRepositionSpeedFactor * sw.speedMmPerS, false, static_cast<int>(k),
                 latticeHash(key, static_cast<std::int64_t>(k), 1, 0));
    }
    traj.add(a, b, sw.speedMmPerS, true, static_cast<int>(k), latticeHash(key, static_cast<std::int64_t>(k), 0, 0));
  }
  return captureArmSweep(s, traj, scan.surfaceZ + offset.z, refToTracker, imageCorners);
}

}  // namespace pp5::sim
