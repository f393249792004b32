#pragma once
// Constant-interval capture (run.capture_interval_mm), after the 1990
// system, which digitised a frame once the probe had moved a set distance
// (2, 3 or 5 mm): a frame is taken when some corner of the image has moved
// at least that far from where it was in the last frame taken. Frames from
// a probe held still or moved slowly add nothing to the volume but work; any
// source (simulator, sequence, board, OpenIGTLink) can be thinned this way.
#include <cstdint>
#include <optional>

#include "core/frame.hpp"
#include "core/transform.hpp"

namespace pp5::host {

class IntervalCapture {
public:
  // 0: every frame.
  explicit IntervalCapture(double intervalMm = 0.0);
  // Whether to take the frame, whose pixels map to millimetres by
  // imageToReference; a taken frame is the reference for the next.
  bool take(const Frame& f, const Mat4& imageToReference);
  double intervalMm() const { return interval_; }
  std::uint64_t taken() const { return taken_; }
  std::uint64_t skipped() const { return skipped_; }

private:
  double interval_;
  std::optional<Mat4> last_;
  std::uint64_t taken_ = 0, skipped_ = 0;
};

}  // namespace pp5::host
