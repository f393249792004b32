#include "core/arm.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace pp5 {

namespace {
}  // namespace

Mat4 probeMountRotation() {
  Mat4 m(1.0);
  m[0] = Vec4(0.0, -1.0, 0.0, 0.0);  // lateral
  m[1] = Vec4(0.0, 0.0, -1.0, 0.0);  // axial: down into the tank
  m[2] = Vec4(1.0, 0.0, 0.0, 0.0);   // elevation
  return m;
}

Mat4 armProbeToTracker(const ArmPose& p, double probeZ) {
  return translation(Vec3(p.xMm, p.yMm, probeZ)) * rotationAxisAngle(Vec3(0, 0, 1), p.thetaDeg * kDegToRad) *
         probeMountRotation();
}

ArmAdc::ArmAdc(double xSpanMm, double ySpanMm, double thetaSpanDeg) {
  perCount_ = {xSpanMm / kMaxCount, ySpanMm / kMaxCount, thetaSpanDeg / kMaxCount};
  // Theta's zero sits exactly on count 2048, so a straight probe reads straight.
  origin_ = {0.0, 0.0, -0.5 * (kMaxCount + 1) * perCount_[2]};
}

std::array<double, 3> ArmAdc::idealCounts(const ArmPose& p) const {
  const std::array<double, 3> v = {p.xMm, p.yMm, p.thetaDeg};
  std::array<double, 3> c{};
  for (std::size_t i = 0; i < 3; ++i) c[i] = (v[i] - origin_[i]) / perCount_[i];
  return c;
}

std::array<int, 3> ArmAdc::read(const ArmPose& p, const std::array<double, 3>& noiseCounts) const {
  const auto ideal = idealCounts(p);
  std::array<int, 3> c{};
  for (std::size_t i = 0; i < 3; ++i)
    c[i] = static_cast<int>(std::clamp(std::lround(ideal[i] + noiseCounts[i]), 0L, static_cast<long>(kMaxCount)));
  return c;
}

ArmPose ArmAdc::calibrate(const std::array<double, 3>& counts) const {
  return {origin_[0] + counts[0] * perCount_[0], origin_[1] + counts[1] * perCount_[1],
          origin_[2] + counts[2] * perCount_[2]};
}

}  // namespace pp5
