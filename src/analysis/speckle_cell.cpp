#include "analysis/speckle_cell.hpp"

#include <algorithm>
#include <cmath>
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
// The variance ratio of a triple is read only where it is more than this share
// of its range away from either end (for evenly spaced frames: rho, the
// correlation over one spacing, under about 0.13 or over 0.96).
constexpr double kElevationReadMargin = 0.05;

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

// Frames whose pixels are differenced must have one size.
void requireSameSize(const Frame& a, const Frame& b) {
  if (a.width != b.width || a.height != b.height)
    throw InputError(fmt::format("frames {} and {} differ in size ({}x{} and {}x{}): no speckle difference between them",
                                 a.index, b.index, a.width, a.height, b.width, b.height));
}

// The difference a - b over the pixels inside the clip rectangle and fan that
// are non-zero in both, in `d`, and which of them are speckle, in `in`.
void speckleDifference(const std::vector<float>& a, const std::vector<float>& b, const std::vector<PixelRun>& runs,
                       int w, int h, std::vector<float>& d, std::vector<std::uint8_t>& in) {
  const std::size_t n = a.size();
  d.assign(n, 0.0f);
  in.assign(n, 0);
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
}

}  // namespace

SpeckleCellMeter::SpeckleCellMeter(int maxLagPx) : maxLag_(std::max(1, maxLagPx)) {
  sumX_.assign(static_cast<std::size_t>(maxLag_) + 1, 0.0);
  sumY_ = sumX_;
  countX_.assign(static_cast<std::size_t>(maxLag_) + 1, 0);
  countY_ = countX_;
}

bool SpeckleCellMeter::add(const Frame& previous, const Frame& current, const std::vector<PixelRun>& runs) {
  requireSameSize(previous, current);
  checkSize(current);
  const int w = current.width, h = current.height;
  const std::vector<float> a = values(previous), b = values(current);

  const std::size_t n = a.size();
  std::vector<float> d;
  std::vector<std::uint8_t> in;
  speckleDifference(a, b, runs, w, h, d, in);
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

void SpeckleCellMeter::checkSize(const Frame& f) {
  if (width_ < 0) {
    width_ = f.width;
    height_ = f.height;
  } else if (f.width != width_ || f.height != height_) {
    throw InputError(fmt::format("frame {} is {}x{}, the frames before it {}x{}: the speckle is measured on one size",
                                 f.index, f.width, f.height, width_, height_));
  }
}

bool SpeckleCellMeter::addTriple(const Frame& a, const Frame& b, const Frame& c, double abMm, double acMm,
                                 const std::vector<PixelRun>& runs) {
  requireSameSize(a, c);
  requireSameSize(b, c);
  checkSize(c);
  if (!(acMm > abMm && abMm > 0.0)) return false;  // not three frames in a row along the sweep
  const std::vector<float> va = values(a), vb = values(b), vc = values(c);
  std::vector<float> d;
  std::vector<std::uint8_t> in;
  speckleDifference(va, vb, runs, c.width, c.height, d, in);
  double s1 = 0.0, q1 = 0.0, s2 = 0.0, q2 = 0.0;
  std::uint64_t n = 0;
  for (std::size_t i = 0; i < in.size(); ++i)
    if (in[i] && vc[i] > 0.0f) {
      const double e1 = d[i], e2 = static_cast<double>(va[i]) - vc[i];
      s1 += e1;
      q1 += e1 * e1;
      s2 += e2;
      q2 += e2 * e2;
      ++n;
    }
  if (n < 2) return false;
  const double k = static_cast<double>(n);
  nearVar_ += q1 / k - (s1 / k) * (s1 / k);
  farVar_ += q2 / k - (s2 / k) * (s2 / k);
  nearMm_ += abMm;
  farMm_ += acMm;
  ++triples_;
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

  c.triples = triples_;
  if (triples_ > 0 && nearVar_ > 0.0) {
    const double t = static_cast<double>(triples_);
    c.nearMm = nearMm_ / t;
    c.farMm = farMm_ / t;
    c.varianceRatio = farVar_ / nearVar_;
    // (1 - rho(far)) / (1 - rho(near)) rises from 1 (s much shorter than the
    // spacing) to (far / near)^2 (s much longer); read only well inside.
    const double top = (c.farMm / c.nearMm) * (c.farMm / c.nearMm);
    const double margin = kElevationReadMargin * (top - 1.0);
    if (c.varianceRatio <= 1.0 + margin) {
      c.elevation = SpeckleCell::Elevation::Decorrelated;
    } else if (c.varianceRatio >= top - margin) {
      c.elevation = SpeckleCell::Elevation::Correlated;
    } else {
      auto ratio = [&](double s) {
        return (1.0 - std::exp(-c.farMm * c.farMm / (2.0 * s * s))) /
               (1.0 - std::exp(-c.nearMm * c.nearMm / (2.0 * s * s)));
      };
      double lo = std::log(1e-3 * c.nearMm), hi = std::log(1e3 * c.nearMm);
      for (int it = 0; it < 100; ++it) {
        const double mid = 0.5 * (lo + hi);
        (ratio(std::exp(mid)) < c.varianceRatio ? lo : hi) = mid;
      }
      c.elevationMm = std::exp(0.5 * (lo + hi)) * std::sqrt(2.0 * std::log(2.0));
      c.elevation = SpeckleCell::Elevation::Measured;
    }
  }
  return c;
}

std::optional<KernelHalfWidths> kernelFromCell(const SpeckleCell& cell, double pixelXMm, double pixelYMm,
                                               double frameSpacingMm, double floorXMm, double floorYMm) {
  if (!cell.lateralPx || !cell.axialPx) return std::nullopt;
  KernelHalfWidths k;
  k.lateralMm = kKernelPerLateralCell * std::max({*cell.lateralPx * pixelXMm, pixelXMm, floorXMm});
  k.axialMm = kKernelPerAxialCell * std::max({*cell.axialPx * pixelYMm, pixelYMm, floorYMm});
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
