#include "interface_board/arm_calibration.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>

#include "core/error.hpp"

namespace pp5::board {

namespace {

const char* channelName(int channel) {
  if (channel < 0 || channel > 2) throw InvariantError(fmt::format("arm channel {} is not 0, 1 or 2", channel));
  return kArmChannelNames[static_cast<std::size_t>(channel)];
}

// Parses one number and skips the blanks before it; false if there is none.
bool parseNumber(const char*& p, const char* end, double& v) {
  while (p < end && (*p == ' ' || *p == '\t')) ++p;
  const auto r = std::from_chars(p, end, v);
  if (r.ec != std::errc{}) return false;
  p = r.ptr;
  return true;
}

}  // namespace

void validateArmTable(const ArmTable& t, int channel, const std::string& key) {
  const char* name = channelName(channel);
  if (t.size() < 2)
    inputError(key, "the arm's {} table has {} point(s); it needs at least 2 (COUNT VALUE rows)", name, t.size());
  for (std::size_t i = 0; i < t.size(); ++i) {
    if (!std::isfinite(t[i].first) || !std::isfinite(t[i].second))
      inputError(key, "the arm's {} table: point {} ({}, {}) is not finite", name, i + 1, t[i].first, t[i].second);
    if (i > 0 && !(t[i].first > t[i - 1].first))
      inputError(key, "the arm's {} table: counts must increase strictly, but point {} has count {} after {}", name,
                 i + 1, t[i].first, t[i - 1].first);
  }
}

ArmTable parseArmTable(const std::vector<std::string>& rows, int channel, const std::string& key) {
  const char* name = channelName(channel);
  ArmTable t;
  t.reserve(rows.size());
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const std::string& row = rows[i];
    const char* p = row.data();
    const char* end = p + row.size();
    double count = 0.0, value = 0.0;
    const bool two = parseNumber(p, end, count) && parseNumber(p, end, value);
    while (p < end && (*p == ' ' || *p == '\t')) ++p;
    if (!two || p != end)
      inputError(key, "the arm's {} table: row {} \"{}\" is not two numbers \"COUNT VALUE\"", name, i + 1, row);
    t.emplace_back(count, value);
  }
  validateArmTable(t, channel, key);
  return t;
}

ArmCalibration ArmCalibration::linear(const ArmAdc& adc, const glm::dvec3& referenceToTrackerMm, double probeZMm) {
  // The converters are linear, so their two end points are the whole table.
  constexpr double kMax = ArmAdc::kMaxCount;
  const ArmPose lo = adc.calibrate({0.0, 0.0, 0.0});
  const ArmPose hi = adc.calibrate({kMax, kMax, kMax});
  ArmCalibration c;
  c.table[0] = {{0.0, lo.xMm}, {kMax, hi.xMm}};
  c.table[1] = {{0.0, lo.yMm}, {kMax, hi.yMm}};
  c.table[2] = {{0.0, lo.thetaDeg}, {kMax, hi.thetaDeg}};
  c.probeZMm = probeZMm;
  c.referenceToTrackerMm = referenceToTrackerMm;
  return c;
}

void ArmCalibration::validate(const std::string& what) const {
  for (int ch = 0; ch < 3; ++ch) validateArmTable(table[static_cast<std::size_t>(ch)], ch, what);
  if (!std::isfinite(probeZMm)) inputError(what, "the probe height {} is not finite", probeZMm);
  for (int i = 0; i < 3; ++i)
    if (!std::isfinite(referenceToTrackerMm[i]))
      inputError(what, "ReferenceToTracker ({}, {}, {}) is not finite", referenceToTrackerMm.x, referenceToTrackerMm.y,
                 referenceToTrackerMm.z);
}

double ArmCalibration::value(int channel, double count) const {
  const ArmTable& t = table[static_cast<std::size_t>(channel)];
  PP5_CHECK_GE(t.size(), std::size_t{2});
  // The segment holding `count`; the end segments also serve outside the table.
  auto it = std::upper_bound(t.begin(), t.end(), count, [](double c, const auto& pt) { return c < pt.first; });
  const auto hiIdx = std::clamp<std::ptrdiff_t>(it - t.begin(), 1, static_cast<std::ptrdiff_t>(t.size()) - 1);
  const auto& a = t[static_cast<std::size_t>(hiIdx - 1)];
  const auto& b = t[static_cast<std::size_t>(hiIdx)];
  return a.second + (count - a.first) * (b.second - a.second) / (b.first - a.first);
}

ArmPose ArmCalibration::toArmPose(const std::array<double, 3>& counts) const {
  return {value(0, counts[0]), value(1, counts[1]), value(2, counts[2])};
}

ArmPose ArmCalibration::toArmPose(std::array<std::uint16_t, 3> counts) const {
  return toArmPose(std::array<double, 3>{double(counts[0]), double(counts[1]), double(counts[2])});
}

Mat4 ArmCalibration::probeToTracker(std::array<std::uint16_t, 3> counts) const {
  return armProbeToTracker(toArmPose(counts), probeZMm);
}

Mat4 ArmCalibration::referenceToTracker() const { return translation(referenceToTrackerMm); }

}  // namespace pp5::board
