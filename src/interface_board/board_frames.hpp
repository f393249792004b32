#pragma once
// Tracked frames to and from the board's wire frames.
//
// The board carries a frame's pixels, its capture time in microseconds and
// one pose: a 6-DOF tracker's matrix (sent as the named per-frame transform,
// e.g. ProbeToTracker) or the 3-DOF arm's raw A/D counts (the frame's
// "ArmCounts" field, as `pp5echo simulate` writes it). On the host the
// counts go through the arm calibration to the same named transform, so
// either way the frame reaches the pipeline with ProbeToTracker set and the
// PLUS configuration's chain places it.
#include <string>

#include "core/frame.hpp"
#include "interface_board/arm_calibration.hpp"
#include "interface_board/wire.hpp"
#include "core/enum_names.hpp"

namespace pp5::board {

PoseKind poseKindFromName(const std::string& name);  // "matrix" | "arm" | "none"

// InputError naming the frame when the pose it needs is missing.
WireFrame toWireFrame(const Frame& f, PoseKind kind, const std::string& transformName);
// `arm` is needed for ArmCounts frames (InputError otherwise).
Frame fromWireFrame(WireFrame&& w, const std::string& transformName, const ArmCalibration* arm);

}  // namespace pp5::board

namespace pp5 {

template <>
struct EnumNames<board::PoseKind> {
  static constexpr std::string_view key = "board pose";
  static constexpr std::array<std::pair<board::PoseKind, std::string_view>, 3> names{{
      {board::PoseKind::Matrix, "matrix"},
      {board::PoseKind::ArmCounts, "arm"},
      {board::PoseKind::None, "none"}}};
};

}  // namespace pp5
