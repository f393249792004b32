#include "reconstruction/fan_mask.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include <fmt/format.h>

#include "core/error.hpp"
#include "reconstruction/fixed_point.hpp"

namespace pp5::gp {

std::vector<PixelRun> pixelRuns(int width, int height, const ReconSettings& s) {
  std::vector<PixelRun> runs;
  if (width <= 0 || height <= 0) return runs;

  std::int64_t cx0 = 0, cx1 = width - 1, cy0 = 0, cy1 = height - 1;
  if (s.clipSize.x > 0 && s.clipSize.y > 0) {
    cx0 = std::max<std::int64_t>(cx0, s.clipOrigin.x);
    cy0 = std::max<std::int64_t>(cy0, s.clipOrigin.y);
    cx1 = std::min<std::int64_t>(cx1, std::int64_t{s.clipOrigin.x} + s.clipSize.x);
    cy1 = std::min<std::int64_t>(cy1, std::int64_t{s.clipOrigin.y} + s.clipSize.y);
    // Not an empty volume without a word (a rectangle made for the uncropped
    // recording, given with a cropped one).
    if (cx0 > cx1 || cy0 > cy1)
      throw InputError(fmt::format("the clip rectangle (origin {} {}, size {} {}) lies outside the {}x{} frames: no "
                                   "pixel would be inserted (was it made for another crop of the recording?)",
                                   s.clipOrigin.x, s.clipOrigin.y, s.clipSize.x, s.clipSize.y, width, height));
  }

  // PLUS's degree-to-radian factor, so the tangents match its bit for bit.
  constexpr double kRadPerDeg = 0.017453292519943295;
  double tanL = std::tan(s.fanAnglesDeg.x * kRadPerDeg);
  double tanR = std::tan(s.fanAnglesDeg.y * kRadPerDeg);
  const bool fan = tanL != 0.0 || tanR != 0.0;
  if (tanL > tanR) std::swap(tanL, tanR);
  const double fx = s.fanOriginPx.x, fy = s.fanOriginPx.y;
  const double rStop = s.fanRadiusStopPx, rStart = s.fanRadiusStartPx;

  using plusmath::ceilPlus;
  using plusmath::floorPlus;
  for (std::int64_t j = cy0; j <= cy1; ++j) {
    std::int64_t xs = cx0, xe = cx1;
    bool skip = false;
    std::int64_t skipStart = 0, skipEnd = -1;
    if (fan) {
      const double y = static_cast<double>(j) - fy;
      if (y <= 0.0) continue;
      xs = std::max(xs, ceilPlus(tanL * y + fx + 1.0));
      xe = std::min(xe, floorPlus(tanR * y + fx - 1.0));
      const double d = rStop * rStop - y * y;
      if (d < 0.0) continue;
      const double dx = std::sqrt(d);
      xs = std::max(xs, ceilPlus(fx - dx + 1.0));
      xe = std::min(xe, floorPlus(fx + dx - 1.0));
      const double d0 = rStart * rStart - y * y;
      if (d0 > 0.0) {
        const double ds = std::sqrt(d0);
        skipStart = ceilPlus(fx - ds + 1.0);
        skipEnd = floorPlus(fx + ds - 1.0);
        skip = true;
      }
    }
    if (xs > xe) continue;
    const int row = static_cast<int>(j);
    if (skip && skipStart < xs) {
      xs = std::max(xs, skipEnd + 1);
      skip = false;
    } else if (skip && skipEnd > xe) {
      xe = std::min(xe, skipStart - 1);
      skip = false;
    }
    if (!skip) {
      if (xs <= xe) runs.push_back({row, static_cast<int>(xs), static_cast<int>(xe)});
      continue;
    }
    if (xs <= skipStart - 1) runs.push_back({row, static_cast<int>(xs), static_cast<int>(skipStart - 1)});
    if (skipEnd + 1 <= xe) runs.push_back({row, static_cast<int>(skipEnd + 1), static_cast<int>(xe)});
  }
  return runs;
}

}  // namespace pp5::gp
