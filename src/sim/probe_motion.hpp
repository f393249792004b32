#pragma once
// How the probe moves and how its pose is measured.
//
// The 1990 system held the probe on a 3-DOF arm: x and y in the plane of the
// tank and a rotation theta about the vertical axis, each read through a
// potentiometer and a 12-bit A/D converter at about 800 Hz. Here the true
// trajectory is sampled by that A/D (quantised, with Gaussian noise),
// calibrated back to mm and degrees, interpolated to each video frame's
// timestamp, and turned into ProbeToTracker by the arm's kinematics. As in the
// paper, a frame is digitised only once the image has moved a set distance
// since the last one, judged on the arm's (noisy) reading.
//
// A freehand sweep instead moves in all six degrees of freedom (drift, heave,
// tilt, roll, yaw and tremor) and is measured by a tracker with optional
// noise; there are no A/D counts then.
//
// Frames: Reference is the phantom's frame; Tracker is the arm's base frame,
// ReferenceToTracker a fixed translation. The probe looks down: at theta = 0
// its lateral axis is -y, its axial axis -z and its elevation axis +x, so
// a sweep along x cuts cross-sections of the phantom.
#include <array>
#include <cstdint>
#include <vector>

#include "core/arm.hpp"
#include "core/transform.hpp"
#include "sim/phantom.hpp"
#include "sim/sim_settings.hpp"

namespace pp5::sim {

// The arm's A/D converters for these settings (core/arm.hpp).
ArmAdc armAdc(const ArmSettings& s);

// A true arm trajectory: straight segments at a hand-cranked (slightly
// uneven, seeded) speed, each with the operator's capture switch on or off.
class ArmTrajectory {
public:
  struct Segment {
    ArmPose from, to;
    double t0 = 0.0, t1 = 0.0;
    bool capture = true;
    int pass = 0;
    double wobblePhase = 0.0;
    int wobbles = 1;
  };
  ArmPose pose(double t) const;
  const Segment& segmentAt(double t) const;
  double duration() const { return segments_.empty() ? 0.0 : segments_.back().t1; }
  const std::vector<Segment>& segments() const { return segments_; }
  // Appends a straight move at `speed` (mm/s on x, y; theta moves with it).
  void add(const ArmPose& from, const ArmPose& to, double speed, bool capture, int pass, std::uint64_t key);

private:
  std::vector<Segment> segments_;
};

// A smooth 6-DOF hand-held path along a line, with seeded wander and tremor.
class FreehandPath {
public:
  FreehandPath(const FreehandSettings& s, const Vec3& start, const Vec3& end, double surfaceZ, double headingDeg,
               double speed, std::uint64_t seed);
  // True ProbeToReference at time t.
  Mat4 probeToReference(double t) const;
  double duration() const { return duration_; }

private:
  struct Wave {
    double amp, freq, phase;
  };
  static double sum(const std::vector<Wave>& w, double t);
  FreehandSettings s_;
  Vec3 start_, end_;
  double surfaceZ_, headingRad_, duration_;
  std::vector<Wave> drift_, heave_, tilt_, roll_, yaw_, along_, tremor_[6];
};

struct CapturedFrame {
  std::uint64_t videoFrame = 0;  // index at the video frame rate
  double timestamp = 0.0;        // videoFrame / frame rate, s
  int pass = 0;
  Mat4 trueProbeToTracker{1.0};  // where the probe really was (images are rendered here)
  Mat4 probeToTracker{1.0};      // what the arm or tracker reported
  bool hasArm = false;
  std::array<int, 3> armCounts{};  // the A/D reading nearest the frame's time
  ArmPose armReported;             // calibrated and interpolated to the frame's time
};

struct Sweep {
  Mat4 referenceToTracker{1.0};
  std::vector<CapturedFrame> frames;
  double duration = 0.0;
  std::uint64_t videoFrames = 0;  // video frames that went by (captured or not)
};


// Plans the sweep of `s.sweep.kind` over the phantom's scan set-up and
// captures frames. `imageCorners` are the image's corners in the Probe frame
// (the capture rule measures how far they moved). Throws InputError when the
// sweep leaves the arm's range.
Sweep planSweep(const SimSettings& s, const ScanSetup& scan, const std::vector<Vec3>& imageCorners);

}  // namespace pp5::sim
