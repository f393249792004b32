#pragma once
// The 3-DOF arm's calibration: A/D counts -> x, y (mm) and theta (degrees)
// -> ProbeToTracker.
//
// Each channel has a piecewise-linear table of (count, value) points with
// strictly increasing counts; a count outside the table extrapolates the end
// segment. A real potentiometer is not quite linear, so a table of many
// points measured on a jig corrects it; the simulator's converters are
// exactly linear and linear() gives the equivalent two-point tables.
#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <glm/glm.hpp>

#include "core/arm.hpp"
#include "core/transform.hpp"

namespace pp5::board {

// Channel numbers, as in the wire header's armCounts: 0 x, 1 y, 2 theta.
constexpr std::array<const char*, 3> kArmChannelNames = {"x", "y", "theta"};

// (count, value) points; value in mm for x and y, degrees for theta.
using ArmTable = std::vector<std::pair<double, double>>;

struct ArmCalibration {
  std::array<ArmTable, 3> table;
  double probeZMm = 0.0;                       // the probe mount's height in the Tracker frame
  glm::dvec3 referenceToTrackerMm{0.0};        // ReferenceToTracker is this translation

  // The two-point tables equal to linear converters (the simulator's,
  // sim::armAdc); probeZMm as the simulator computes it (scan surface z +
  // reference_to_tracker_mm.z).
  static ArmCalibration linear(const ArmAdc& adc, const glm::dvec3& referenceToTrackerMm, double probeZMm);

  // Throws InputError naming `what` and the channel when a table is unusable
  // (fewer than 2 points, counts not strictly increasing, a non-finite number)
  // or the offsets are not finite.
  void validate(const std::string& what = "arm calibration") const;

  // One channel's value at a (possibly fractional) count.
  double value(int channel, double count) const;
  ArmPose toArmPose(const std::array<double, 3>& counts) const;
  ArmPose toArmPose(std::array<std::uint16_t, 3> counts) const;
  // The arm's kinematics (armProbeToTracker, core/arm.hpp) at the calibrated pose.
  Mat4 probeToTracker(std::array<std::uint16_t, 3> counts) const;
  Mat4 referenceToTracker() const;
};

// Checks one table; `key` names it in the message (e.g. the configuration key).
void validateArmTable(const ArmTable& t, int channel, const std::string& key);

// Parses a table from rows "COUNT VALUE" (two numbers separated by blanks),
// as the configuration stores it, and validates it. Throws InputError naming
// `key`, the channel and the bad row.
ArmTable parseArmTable(const std::vector<std::string>& rows, int channel, const std::string& key);

}  // namespace pp5::board
