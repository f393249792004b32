#include "host/capture.hpp"

#include <array>

#include "core/error.hpp"

namespace pp5::host {

IntervalCapture::IntervalCapture(double intervalMm) : interval_(intervalMm) {
  if (!(intervalMm >= 0.0)) throw InputError("run.capture_interval_mm must be 0 (every frame) or a distance in mm");
}

bool IntervalCapture::take(const Frame& f, const Mat4& imageToReference) {
  if (interval_ > 0.0 && last_) {
    const double w = f.width, h = f.height;
    const std::array<Vec3, 4> corners{Vec3(0, 0, 0), Vec3(w, 0, 0), Vec3(0, h, 0), Vec3(w, h, 0)};
    if (largestDisplacement(*last_, imageToReference, corners) < interval_) {
      ++skipped_;
      return false;
    }
  }
  last_ = imageToReference;
  ++taken_;
  return true;
}

}  // namespace pp5::host
