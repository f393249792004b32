#include "gp/speckle_cell.hpp"

#include <algorithm>
#include <cstddef>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::gp {

namespace {

// Blocks of kBlock x kBlock pixels are kept where the difference's correlation
// between horizontal neighbours exceeds kMinNeighbourCorrelation (chosen on
// the simulated doll in its water bath, docs/quality.md).
constexpr int kBlock = 32;
constexpr double kMinNeighbourCorrelation = 0.2;

std::vector<float> values(const Frame& f) {
  const std::size_t n = static_cast<std::size_t>(f.width) * static_cast<std::size_t>(f.height);
  std::vector<float> v(n);
  if (f.pixelType == PixelType::U8) {
    for (std::size_t i = 0; i < n; ++i) v[i] = f.pixels[i];
  } else {
    for (std::size_t i = 0; i < n; ++i)
      v[i] = static_cast<float>(static_cast<std::uint16_t>(f.pixels[2 * i] | (f.pixels[2 * i + 1] << 8)));
  }
  return v;
}


}  // namespace

SpeckleCellMeter::SpeckleCellMeter(int maxLagPx) : maxLag_(std::max(1, maxLagPx)) {
  sumX_.assign(static_cast<std::size_t>(maxLag_) + 1, 0.0);
  sumY_ = sumX_;
  countX_.assign(static_cast<std::size_t>(maxLag_) + 1, 0);
  countY_ = countX_;
}

bool SpeckleCellMeter::add(const Frame& previous, const Frame& current, const std::vector<PixelRun>& runs) {
  if (previous.width != current.width || previous.height != current.height)
    throw InputError(fmt::format("frames {} and {} differ in size ({}x{} and {}x{}): no speckle difference between them",
                                 previous.index, current.index, previous.width, previous.height, current.width,
                                 current.height));
  if (width_ < 0) {
    width_ = current.width;
    height_ = current.height;
  } else if (current.width != width_ || current.height != height_) {
    throw InputError(fmt::format("frame {} is {}x{}, the frames before it {}x{}: the speckle is measured on one size",
                                 current.index, current.width, current.height, width_, height_));
  }
  const int w = current.width, h = current.height;
  const std::vector<float> a = values(previous), b = values(current);

  // The difference over the non-zero pixels of both frames inside the clip
  // rectangle and fan.
  const std::size_t n = a.size();
  std::vector<float> d(n, 0.0f);
  std::vector<std::uint8_t> in(n, 0);
  for (const PixelRun& r : runs)
    for (int x = r.x0; x <= r.x1; ++x) {
      const std::size_t i = static_cast<std::size_t>(r.y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x);
      if (a[i] > 0.0f && b[i] > 0.0f) {
        d[i] = a[i] - b[i];
        in[i] = 1;
      }
    }
  // Only the blocks whose difference is correlated from one pixel to the
  // next along the rows: the others hold white noise (a water bath, a shadow,
  // made as bright as tissue by the time-gain compensation), not speckle.
  for (int by = 0; by < h; by += kBlock)
    for (int bx = 0; bx < w; bx += kBlock) {
      const int ey = std::min(h, by + kBlock), ex = std::min(w, bx + kBlock);
      double s0 = 0.0, s1 = 0.0, m = 0.0;
      std::uint64_t c0 = 0, c1 = 0;
      for (int y = by; y < ey; ++y)
        for (int x = bx; x < ex; ++x) {
          const std::size_t i = static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x);
          if (in[i]) {
            m += d[i];
            ++c0;
          }
        }
      if (c0 > 0) m /= static_cast<double>(c0);
      for (int y = by; y < ey; ++y)
        for (int x = bx; x < ex; ++x) {
          const std::size_t i = static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x);
          if (!in[i]) continue;
          s0 += (d[i] - m) * (d[i] - m);
          if (x + 1 < ex && in[i + 1]) {
            s1 += (d[i] - m) * (d[i + 1] - m);
            ++c1;
          }
        }
      const bool speckle = 2 * c0 >= static_cast<std::uint64_t>(ex - bx) * static_cast<std::uint64_t>(ey - by) &&
                           c1 > 0 && s0 > 0.0 &&
                           (s1 / static_cast<double>(c1)) / (s0 / static_cast<double>(c0)) > kMinNeighbourCorrelation;
      if (!speckle)
        for (int y = by; y < ey; ++y)
          std::fill_n(in.begin() + static_cast<std::ptrdiff_t>(static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + bx),
                      ex - bx, std::uint8_t{0});
    }
  // Less the mean of what is left.
  double mean = 0.0;
  std::uint64_t count = 0;
  for (std::size_t i = 0; i < n; ++i)
    if (in[i]) {
      mean += d[i];
      ++count;
    }
  if (count == 0) return false;
  mean /= static_cast<double>(count);
  for (std::size_t i = 0; i < n; ++i)
    if (in[i]) d[i] -= static_cast<float>(mean);

  for (int lag = 0; lag <= maxLag_; ++lag) {
    double sx = 0.0, sy = 0.0;
    std::uint64_t cx = 0, cy = 0;
    for (int y = 0; y < h; ++y) {
      const std::size_t row = static_cast<std::size_t>(y) * static_cast<std::size_t>(w);
      for (int x = 0; x + lag < w; ++x)
        if (in[row + x] && in[row + x + lag]) {
          sx += static_cast<double>(d[row + x]) * d[row + x + lag];
          ++cx;
        }
      if (y + lag < h) {
        const std::size_t below = row + static_cast<std::size_t>(lag) * static_cast<std::size_t>(w);
        for (int x = 0; x < w; ++x)
          if (in[row + x] && in[below + x]) {
            sy += static_cast<double>(d[row + x]) * d[below + x];
            ++cy;
          }
      }
    }
    sumX_[lag] += sx;
    sumY_[lag] += sy;
    countX_[lag] += cx;
    countY_[lag] += cy;
  }
  ++pairs_;
  pixels_ += count;
  return true;
}

SpeckleCell SpeckleCellMeter::result() const {
  SpeckleCell c;
  c.pairs = pairs_;
  c.pixels = pixels_;
  auto normalise = [](const std::vector<double>& sum, const std::vector<std::uint64_t>& count) {
    std::vector<double> r;
    if (count[0] == 0 || !(sum[0] > 0.0)) return r;  // nothing measured, or two identical frames
    const double v0 = sum[0] / static_cast<double>(count[0]);
    for (std::size_t lag = 0; lag < sum.size() && count[lag] > 0; ++lag)
      r.push_back(sum[lag] / static_cast<double>(count[lag]) / v0);
    return r;
  };
  c.lateral = normalise(sumX_, countX_);
  c.axial = normalise(sumY_, countY_);
  c.lateralPx = halfWidthAtHalfMaximum(c.lateral);
  c.axialPx = halfWidthAtHalfMaximum(c.axial);
  return c;
}

std::optional<KernelHalfWidths> kernelFromCell(const SpeckleCell& cell, double pixelXMm, double pixelYMm,
                                               double frameSpacingMm) {
  if (!cell.lateralPx || !cell.axialPx) return std::nullopt;
  KernelHalfWidths k;
  k.lateralMm = kKernelPerLateralCell * std::max(*cell.lateralPx, 1.0) * pixelXMm;
  k.axialMm = kKernelPerAxialCell * std::max(*cell.axialPx, 1.0) * pixelYMm;
  k.elevationMm = kKernelPerFrameSpacing * frameSpacingMm;
  return k;
}

std::optional<double> halfWidthAtHalfMaximum(const std::vector<double>& r) {
  for (std::size_t lag = 1; lag < r.size(); ++lag)
    if (r[lag] < 0.5) {
      const double hi = r[lag - 1], lo = r[lag];
      return static_cast<double>(lag - 1) + (hi - 0.5) / (hi - lo);
    }
  return std::nullopt;
}

}  // namespace pp5::gp
