#pragma once
// The 1990 system's 3-DOF arm, as hardware: x and y in the plane of the tank
// and a rotation theta about the vertical axis, each read through a
// potentiometer and a 12-bit A/D converter. The interface board's driver
// reads it and the simulator imitates it; both take its model from here.
//
// The probe looks down: at theta = 0 its lateral axis is -y, its axial axis
// -z and its elevation axis +x of the arm's base (Tracker) frame.
#include <array>

#include "core/transform.hpp"

namespace pp5 {

struct ArmPose {
  double xMm = 0.0, yMm = 0.0, thetaDeg = 0.0;  // in the Tracker frame
};

// Probe axes in the Tracker frame at theta = 0 (rotation only).
Mat4 probeMountRotation();
// The arm's kinematics: translation (x, y, probeZ), then theta about +z.
Mat4 armProbeToTracker(const ArmPose& p, double probeZ);

// The arm's 12-bit A/D converters and their linear calibration (x and y from
// 0, theta centred on 0).
class ArmAdc {
public:
  static constexpr int kMaxCount = 4095;
  // The travel of each channel over counts 0..kMaxCount.
  ArmAdc(double xSpanMm, double ySpanMm, double thetaSpanDeg);
  // Counts that a noise-free converter with infinite resolution would give.
  std::array<double, 3> idealCounts(const ArmPose& p) const;
  // One reading: ideal counts plus noise (in counts), rounded and clamped to 0..4095.
  std::array<int, 3> read(const ArmPose& p, const std::array<double, 3>& noiseCounts) const;
  // Calibration: counts (fractional after interpolation) -> mm and degrees.
  ArmPose calibrate(const std::array<double, 3>& counts) const;
  // mm (or degrees) per count of each channel.
  double resolution(int channel) const { return perCount_[static_cast<std::size_t>(channel)]; }

private:
  std::array<double, 3> origin_{}, perCount_{};
};

}  // namespace pp5
