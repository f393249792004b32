#include "analysis/wire_segmentation.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <numbers>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::calib {
namespace {

// Sliding min (or max) over windows of 2h+1 along a row of n values (van Herk
// and Gil-Werman: prefix and suffix extremes per block, three comparisons a
// value). Outside the row counts as `outside`.
template <class Op>
void slideRow(const std::uint8_t* in, int n, int h, std::uint8_t outside, std::uint8_t* out, std::vector<std::uint8_t>& g,
              std::vector<std::uint8_t>& hbuf, Op op) {
  const int k = 2 * h + 1;
  const int padded = n + 2 * h;
  const int blocks = (padded + k - 1) / k;
  const int len = blocks * k;
  g.resize(static_cast<std::size_t>(len));
  hbuf.resize(static_cast<std::size_t>(len));
  auto at = [&](int i) { return (i >= h && i < h + n) ? in[i - h] : outside; };
  for (int b = 0; b < blocks; ++b) {
    const int s = b * k;
    g[static_cast<std::size_t>(s)] = at(s);
    for (int i = s + 1; i < s + k; ++i) g[static_cast<std::size_t>(i)] = op(g[static_cast<std::size_t>(i - 1)], at(i));
    hbuf[static_cast<std::size_t>(s + k - 1)] = at(s + k - 1);
    for (int i = s + k - 2; i >= s; --i) hbuf[static_cast<std::size_t>(i)] = op(hbuf[static_cast<std::size_t>(i + 1)], at(i));
  }
  // Window [x, x + k - 1] in padded coordinates is output x.
  for (int x = 0; x < n; ++x) out[x] = op(hbuf[static_cast<std::size_t>(x)], g[static_cast<std::size_t>(x + k - 1)]);
}

template <class Op>
std::vector<std::uint8_t> morph(const std::vector<std::uint8_t>& image, int w, int h, int radius, std::uint8_t outside,
                                Op op) {
  // A disc is the union of horizontal segments, one per row offset dy with
  // half width floor(sqrt(r^2 - dy^2)): slide each distinct width along the
  // rows, then combine the rows.
  std::vector<int> halfWidth(static_cast<std::size_t>(2 * radius + 1));
  for (int dy = -radius; dy <= radius; ++dy)
    halfWidth[static_cast<std::size_t>(dy + radius)] =
        static_cast<int>(std::floor(std::sqrt(static_cast<double>(radius * radius - dy * dy)) + 1e-9));
  std::vector<std::vector<std::uint8_t>> rows(static_cast<std::size_t>(radius + 1));
  std::vector<std::uint8_t> g, hb;
  for (int hw = 0; hw <= radius; ++hw) {
    if (std::find(halfWidth.begin(), halfWidth.end(), hw) == halfWidth.end()) continue;
    auto& r = rows[static_cast<std::size_t>(hw)];
    r.resize(image.size());
    for (int y = 0; y < h; ++y)
      slideRow(image.data() + static_cast<std::size_t>(y) * static_cast<std::size_t>(w), w, hw, outside,
               r.data() + static_cast<std::size_t>(y) * static_cast<std::size_t>(w), g, hb, op);
  }
  std::vector<std::uint8_t> out(image.size());
  for (int y = 0; y < h; ++y) {
    std::uint8_t* o = out.data() + static_cast<std::size_t>(y) * static_cast<std::size_t>(w);
    std::fill(o, o + w, outside);
    for (int dy = -radius; dy <= radius; ++dy) {
      const int yy = y + dy;
      if (yy < 0 || yy >= h) continue;
      const std::uint8_t* r = rows[static_cast<std::size_t>(halfWidth[static_cast<std::size_t>(dy + radius)])].data() +
                              static_cast<std::size_t>(yy) * static_cast<std::size_t>(w);
      for (int x = 0; x < w; ++x) o[x] = op(o[x], r[x]);
    }
  }
  return out;
}

struct Line {
  int dots[3];     // candidate indices, ordered by image x
  Vec2 mid;        // midpoint of the outer dots
  Vec2 dir;        // unit direction, left to right
  double lengthMm;  // outer dots apart
  double offLineMm;  // the middle dot's distance from the outer dots' line
};

}  // namespace

std::vector<std::uint8_t> openWithDisc(const std::vector<std::uint8_t>& image, int w, int h, int radius) {
  PP5_CHECK_EQ(image.size(), static_cast<std::size_t>(w) * static_cast<std::size_t>(h));
  if (radius <= 0) return image;
  auto mn = [](std::uint8_t a, std::uint8_t b) { return a < b ? a : b; };
  auto mx = [](std::uint8_t a, std::uint8_t b) { return a > b ? a : b; };
  return morph(morph(image, w, h, radius, 255, mn), w, h, radius, 0, mx);
}

WireSegmentation segmentWires(const Frame& frame, const PlusSegmentation& s, const NWirePhantom& phantom) {
  if (frame.pixelType != PixelType::U8)
    throw InputError(fmt::format("frame {}: calibration needs 8-bit B-mode frames", frame.index));
  WireSegmentation out;
  const double sp = s.approximateSpacingMmPerPixel;
  // The clip rectangle, within the frame.
  const int x0 = std::clamp(s.clipRectangleOrigin.x, 0, frame.width);
  const int y0 = std::clamp(s.clipRectangleOrigin.y, 0, frame.height);
  const int cw = s.clipRectangleSize.x > 0 ? std::min(s.clipRectangleSize.x, frame.width - x0) : frame.width - x0;
  const int ch = s.clipRectangleSize.y > 0 ? std::min(s.clipRectangleSize.y, frame.height - y0) : frame.height - y0;
  if (cw <= 2 || ch <= 2) {
    out.why = "the clip rectangle leaves no image";
    return out;
  }
  std::vector<std::uint8_t> clip(static_cast<std::size_t>(cw) * static_cast<std::size_t>(ch));
  for (int y = 0; y < ch; ++y)
    std::copy_n(frame.u8() + static_cast<std::size_t>(y0 + y) * static_cast<std::size_t>(frame.width) + x0, cw,
                clip.data() + static_cast<std::size_t>(y) * static_cast<std::size_t>(cw));
  const int radius = static_cast<int>(std::lround(s.morphologicalOpeningCircleRadiusMm / sp));
  const std::vector<std::uint8_t> opened = openWithDisc(clip, cw, ch, radius);

  const auto [mnIt, mxIt] = std::minmax_element(opened.begin(), opened.end());
  const double lo = *mnIt, hi = *mxIt;
  if (hi <= lo) {
    out.why = "the image is flat";
    return out;
  }
  const double threshold = lo + (hi - lo) * s.thresholdImagePercent / 100.0;

  // Blobs above the threshold (8-connected), each as a weighted centroid. A blob
  // wider than half the narrowest pattern, or taller than half the smallest
  // gap between patterns, is a wall or a reverberation, not one wire crossing
  // the plane.
  double narrowest = phantom.outerSpacingMm(0), gap = 1e300;
  for (int k = 0; k < phantom.patternCount(); ++k) narrowest = std::min(narrowest, phantom.outerSpacingMm(k));
  for (int k = 0; k + 1 < phantom.patternCount(); ++k) gap = std::min(gap, phantom.planeDistanceMm(k));
  if (gap > 1e299) gap = narrowest;
  const double maxWidthPx = 0.5 * narrowest / sp, maxHeightPx = 0.5 * gap / sp;
  std::vector<std::uint8_t> seen(opened.size(), 0);
  std::vector<int> stack;
  std::vector<DotCandidate> dots;
  for (int y = 0; y < ch; ++y)
    for (int x = 0; x < cw; ++x) {
      const std::size_t i0 = static_cast<std::size_t>(y) * static_cast<std::size_t>(cw) + static_cast<std::size_t>(x);
      if (seen[i0] || opened[i0] <= threshold) continue;
      seen[i0] = 1;
      stack.assign(1, static_cast<int>(i0));
      double sw = 0.0, sx = 0.0, sy = 0.0, score = 0.0;
      int area = 0, bx0 = x, bx1 = x, by0 = y, by1 = y;
      while (!stack.empty()) {
        const int i = stack.back();
        stack.pop_back();
        const int px = i % cw, py = i / cw;
        const double v = opened[static_cast<std::size_t>(i)];
        const double wgt = v - threshold;
        sw += wgt;
        sx += wgt * px;
        sy += wgt * py;
        score += s.useOriginalImageIntensityForDotIntensityScore ? clip[static_cast<std::size_t>(i)] : v;
        ++area;
        bx0 = std::min(bx0, px), bx1 = std::max(bx1, px), by0 = std::min(by0, py), by1 = std::max(by1, py);
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const int nx = px + dx, ny = py + dy;
            if (nx < 0 || ny < 0 || nx >= cw || ny >= ch) continue;
            const std::size_t j = static_cast<std::size_t>(ny) * static_cast<std::size_t>(cw) + static_cast<std::size_t>(nx);
            if (seen[j] || opened[j] <= threshold) continue;
            seen[j] = 1;
            stack.push_back(static_cast<int>(j));
          }
      }
      if (bx1 - bx0 + 1 > maxWidthPx || by1 - by0 + 1 > maxHeightPx) continue;
      if (sw <= 0.0) continue;
      dots.push_back({Vec2(x0 + sx / sw, y0 + sy / sw), score, area});
    }
  std::sort(dots.begin(), dots.end(), [](const DotCandidate& a, const DotCandidate& b) { return a.score > b.score; });
  if (dots.size() > static_cast<std::size_t>(s.numberOfMaximumFiducialPointCandidates))
    dots.resize(static_cast<std::size_t>(s.numberOfMaximumFiducialPointCandidates));
  out.candidates = dots;

  const int P = phantom.patternCount();
  if (static_cast<int>(dots.size()) < 3 * P) {
    out.why = fmt::format("{} dot candidates, {} needed", dots.size(), 3 * P);
    return out;
  }

  // Collinear triples.
  const double deg = std::numbers::pi / 180.0;
  std::vector<Line> lines;
  const int n = static_cast<int>(dots.size());
  for (int i = 0; i < n; ++i)
    for (int j = i + 1; j < n; ++j)
      for (int k = j + 1; k < n; ++k) {
        int idx[3] = {i, j, k};
        std::sort(idx, idx + 3, [&](int a, int b) { return dots[static_cast<std::size_t>(a)].position.x <
                                                           dots[static_cast<std::size_t>(b)].position.x; });
        const Vec2 a = dots[static_cast<std::size_t>(idx[0])].position;
        const Vec2 b = dots[static_cast<std::size_t>(idx[1])].position;
        const Vec2 c = dots[static_cast<std::size_t>(idx[2])].position;
        const Vec2 ac = c - a;
        const double len = glm::length(ac);
        if (len <= 0.0) continue;
        const Vec2 dir = ac / len;
        const double u = ratioAlong(a, b, c);
        if (u <= 0.02 || u >= 0.98) continue;
        const Vec2 ab = b - a;
        const double off = std::abs(ab.x * dir.y - ab.y * dir.x) * sp;
        if (off > s.collinearPointsMaxDistanceFromLineMm) continue;
        const double theta = std::atan2(dir.y, dir.x) / deg;  // (-90, 90] since dir.x >= 0
        if (theta < s.minThetaDegrees || theta > s.maxThetaDegrees) continue;
        lines.push_back({{idx[0], idx[1], idx[2]}, 0.5 * (a + c), dir, len * sp, off});
      }
  out.collinearTriples = static_cast<int>(lines.size());
  if (static_cast<int>(lines.size()) < P) {
    out.why = fmt::format("{} collinear triples among {} candidates, {} needed", lines.size(), dots.size(), P);
    return out;
  }

  // One line per pattern, top (nearest the probe face) to bottom, with disjoint
  // dots: each as long as its pattern's outer wires are apart (longer by up to
  // the angle tolerance's slant), consecutive ones parallel within the angle
  // difference, as far apart as the patterns' planes and not shifted along
  // each other by more than the line shift. The set with the smallest summed
  // relative mismatch wins.
  const double tol = s.maxLinePairDistanceErrorPercent / 100.0;
  const double slant = 1.0 / std::cos(s.angleToleranceDegrees * deg);
  auto lengthOk = [&](const Line& l, int k) {
    const double want = phantom.outerSpacingMm(k);
    return l.lengthMm >= want * (1.0 - tol) && l.lengthMm <= want * (1.0 + tol) * slant;
  };
  std::vector<int> chosen(static_cast<std::size_t>(P), -1), best;
  double bestCost = 1e300;
  std::function<void(int, double)> search = [&](int k, double cost) {
    if (cost >= bestCost) return;
    if (k == P) {
      bestCost = cost;
      best = chosen;
      return;
    }
    for (int li = 0; li < static_cast<int>(lines.size()); ++li) {
      const Line& l = lines[static_cast<std::size_t>(li)];
      if (!lengthOk(l, k)) continue;
      bool clash = false;
      for (int q = 0; q < k && !clash; ++q)
        for (int a : lines[static_cast<std::size_t>(chosen[static_cast<std::size_t>(q)])].dots)
          for (int b : l.dots) clash = clash || a == b;
      if (clash) continue;
      double c = cost + std::abs(l.lengthMm / phantom.outerSpacingMm(k) - 1.0) +
                 l.offLineMm / std::max(s.collinearPointsMaxDistanceFromLineMm, 1e-9) * 0.1;
      if (k > 0) {
        const Line& prev = lines[static_cast<std::size_t>(chosen[static_cast<std::size_t>(k - 1)])];
        const double angle = std::acos(std::clamp(glm::dot(prev.dir, l.dir), -1.0, 1.0)) / deg;
        if (angle > s.maxAngleDifferenceDegrees) continue;
        const Vec2 d = l.mid - prev.mid;
        const double across = (d.x * -prev.dir.y + d.y * prev.dir.x) * sp;  // > 0: below prev (image y down)
        const double along = std::abs(glm::dot(d, prev.dir)) * sp;
        const double want = phantom.planeDistanceMm(k - 1);
        if (across <= 0.0 || std::abs(across - want) > want * tol || along > s.maxLineShiftMm) continue;
        c += std::abs(across / want - 1.0);
      }
      chosen[static_cast<std::size_t>(k)] = li;
      search(k + 1, c);
    }
  };
  search(0, 0.0);
  if (best.empty()) {
    out.why = fmt::format("no {} of the {} collinear triples fit the phantom's patterns", P, lines.size());
    return out;
  }
  out.found = true;
  for (int li : best) {
    const Line& l = lines[static_cast<std::size_t>(li)];
    out.patterns.push_back({dots[static_cast<std::size_t>(l.dots[0])].position, dots[static_cast<std::size_t>(l.dots[1])].position,
                            dots[static_cast<std::size_t>(l.dots[2])].position});
  }
  return out;
}

}  // namespace pp5::calib
