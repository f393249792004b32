#include "interface_board/board_frames.hpp"

#include <cmath>
#include <sstream>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::board {

PoseKind poseKindFromName(const std::string& name) { return enumFromName<PoseKind>(name); }

WireFrame toWireFrame(const Frame& f, PoseKind kind, const std::string& transformName) {
  WireFrame w;
  w.sequence = static_cast<std::uint32_t>(f.index);
  w.timestampUs = static_cast<std::uint64_t>(std::llround(std::max(0.0, f.timestamp) * 1e6));
  if (f.width > 0xffff || f.height > 0xffff)
    throw InputError(fmt::format("frame {}: {}x{} is too large for the board", f.index, f.width, f.height));
  w.width = static_cast<std::uint16_t>(f.width);
  w.height = static_cast<std::uint16_t>(f.height);
  w.bytesPerPixel = static_cast<std::uint8_t>(bytesPerPixel(f.pixelType));
  w.pixels = f.pixels;
  if (!f.imageValid) w.flags |= kFlagImageInvalid;
  w.poseKind = kind;
  if (kind == PoseKind::Matrix) {
    const FrameTransform* t = f.findTransform(transformName);
    if (!t) throw InputError(fmt::format("frame {}: no {} transform to send as the board's pose", f.index, transformName));
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) w.matrix[static_cast<std::size_t>(4 * r + c)] = t->matrix[c][r];
    if (!t->valid) w.flags |= kFlagPoseInvalid;
  } else if (kind == PoseKind::ArmCounts) {
    const std::string* field = f.findField("ArmCounts");
    if (!field) throw InputError(fmt::format("frame {}: no ArmCounts field to send as the board's arm reading", f.index));
    std::istringstream in(*field);
    for (auto& c : w.armCounts) {
      int v = -1;
      if (!(in >> v) || v < 0 || v > 4095)
        throw InputError(fmt::format("frame {}: ArmCounts '{}' is not three counts 0..4095", f.index, *field));
      c = static_cast<std::uint16_t>(v);
    }
  }
  return w;
}

Frame fromWireFrame(WireFrame&& w, const std::string& transformName, const ArmCalibration* arm) {
  Frame f;
  f.width = w.width;
  f.height = w.height;
  f.pixelType = w.bytesPerPixel == 2 ? PixelType::U16 : PixelType::U8;
  f.pixels = std::move(w.pixels);
  f.index = w.sequence;
  f.timestamp = static_cast<double>(w.timestampUs) * 1e-6;
  f.imageValid = (w.flags & kFlagImageInvalid) == 0;
  const bool poseValid = (w.flags & kFlagPoseInvalid) == 0;
  if (w.poseKind == PoseKind::Matrix) {
    Mat4 m(1.0);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) m[c][r] = w.matrix[static_cast<std::size_t>(4 * r + c)];
    f.setTransform(transformName, m, poseValid);
  } else if (w.poseKind == PoseKind::ArmCounts) {
    if (!arm) throw InputError("the board sends arm readings but no arm calibration is configured ([board] arm_*)");
    f.setTransform(transformName, arm->probeToTracker(w.armCounts), poseValid);
    f.customFields.emplace_back("ArmCounts", fmt::format("{} {} {}", w.armCounts[0], w.armCounts[1], w.armCounts[2]));
  }
  return f;
}

}  // namespace pp5::board
