#include "rendering/dbuffer.hpp"

#include <algorithm>
#include <bit>
#include <climits>
#include <cmath>
#include <cstring>
#include <limits>

#include "core/error.hpp"

namespace pp5::gp {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// A face polygon after near clipping: at most one more vertex than the quad.
struct Poly {
  glm::dvec2 v[5];
  int n = 0;
  std::uint8_t id = 0;  // 1 + 2 * axis + side
};

// Lexicographic order on camera-space points: the two faces that share an
// edge see its endpoints in opposite orders, and must cut it at the same point.
bool before(const Vec3& a, const Vec3& b) {
  if (a.z != b.z) return a.z < b.z;
  if (a.x != b.x) return a.x < b.x;
  return a.y < b.y;
}

// Sutherland-Hodgman against z >= zNear, one plane.
int clipNear(const Vec3 (&in)[4], double zNear, Vec3 (&out)[5]) {
  int n = 0;
  for (int i = 0; i < 4; ++i) {
    const Vec3& a = in[i];
    const Vec3& b = in[(i + 1) % 4];
    const bool ina = a.z >= zNear, inb = b.z >= zNear;
    if (ina) out[n++] = a;
    if (ina != inb) {
      const Vec3& p = before(a, b) ? a : b;
      const Vec3& q = before(a, b) ? b : a;
      const double s = (zNear - p.z) / (q.z - p.z);
      out[n++] = Vec3(p.x + (q.x - p.x) * s, p.y + (q.y - p.y) * s, zNear);
    }
  }
  return n;
}

// Pixel columns whose centre lies in [a, b): ceil(a - 0.5) .. ceil(b - 0.5) - 1.
inline double firstCentre(double a) { return std::ceil(a - 0.5); }

}  // namespace

void DBuffer::reset(const Camera& camera) {
  const bool sameSize = camera.width == rays_.width() && camera.height == rays_.height() && !slot_.empty();
  rays_ = PixelRays(camera);
  const std::size_t n = static_cast<std::size_t>(camera.width) * static_cast<std::size_t>(camera.height);
  if (sameSize && slot_.size() == n) {
    for (const auto p : touched_) slot_[p] = kNone;
  } else {
    slot_.assign(n, kNone);
  }
  touched_.clear();
  entries_.clear();
  stats_ = {};
  rowLo_.assign(static_cast<std::size_t>(camera.height), INT_MAX);
  rowHi_.assign(static_cast<std::size_t>(camera.height), -1);
  if (rays_.perspective()) {
    if (dirs_.size() != n || !(dirsCamera_ == camera)) {
      dirs_.resize(n);
      dirsLo_.assign(static_cast<std::size_t>(camera.height), 0);
      dirsHi_.assign(static_cast<std::size_t>(camera.height), 0);
      dirsCamera_ = camera;
    }
  }
}

const Vec3* DBuffer::rowDirs(int y, int x0, int x1) {
  int& lo = dirsLo_[static_cast<std::size_t>(y)];
  int& hi = dirsHi_[static_cast<std::size_t>(y)];
  Vec3* row = dirs_.data() + static_cast<std::size_t>(y) * static_cast<std::size_t>(rays_.width());
  auto fill = [&](int a, int b) {
    for (int x = a; x < b; ++x) row[x] = rays_.ray(x, y).dir;
  };
  if (lo == hi) {
    fill(x0, x1);
    lo = x0;
    hi = x1;
  } else {
    // Keep one interval: what lies between the old one and the new is filled too.
    if (x0 < lo) fill(x0, lo);
    if (x1 > hi) fill(hi, x1);
    lo = std::min(lo, x0);
    hi = std::max(hi, x1);
  }
  return row;
}

void DBuffer::build(const Camera& camera, std::span<const WorldBox> boxes) {
  reset(camera);
  addBoxes(boxes);
  finish();
}

void DBuffer::finish() {
  // Ascending pixel order, read back off the slot table row by row within
  // each row's range of touched columns (cheaper than sorting the list).
  const std::size_t n = touched_.size();
  const auto W = static_cast<std::size_t>(rays_.width());
  std::size_t at = 0;
  for (std::size_t y = 0; y < rowLo_.size(); ++y) {
    if (rowLo_[y] > rowHi_[y]) continue;
    for (std::size_t p = y * W + static_cast<std::size_t>(rowLo_[y]); p <= y * W + static_cast<std::size_t>(rowHi_[y]); ++p)
      if (slot_[p] != kNone) touched_[at++] = static_cast<std::uint32_t>(p);
    rowLo_[y] = INT_MAX;
    rowHi_[y] = -1;
  }
  PP5_CHECK_EQ(at, n);
}

void DBuffer::insert(std::uint32_t pixel, double tIn, double tOut) {
  // Rounded outwards. 0 <= tIn <= tOut: a rounded above tIn is above 0,
  // and b rounded below tOut is finite and not negative, so one step of the
  // bits moves each by one float towards the outside.
  float a = static_cast<float>(tIn), b = static_cast<float>(tOut);
  if (static_cast<double>(a) > tIn) a = std::bit_cast<float>(std::bit_cast<std::uint32_t>(a) - 1u);
  if (static_cast<double>(b) < tOut) b = std::bit_cast<float>(std::bit_cast<std::uint32_t>(b) + 1u);
  if (slot_[pixel] == kNone) {
    slot_[pixel] = static_cast<std::uint32_t>(entries_.size());
    touched_.push_back(pixel);
    entries_.emplace_back();
  }
  Entry& e = entries_[slot_[pixel]];
  Span merged{a, b};
  Span kept[kMaxSpans + 1];
  int n = 0;
  for (int i = 0; i < e.n; ++i) {
    const Span s = e.s[i];
    if (s.tIn <= merged.tOut && s.tOut >= merged.tIn) {
      merged.tIn = std::min(merged.tIn, s.tIn);
      merged.tOut = std::max(merged.tOut, s.tOut);
    } else {
      kept[n++] = s;
    }
  }
  int at = 0;
  while (at < n && kept[at].tIn < merged.tIn) ++at;
  for (int i = n; i > at; --i) kept[i] = kept[i - 1];
  kept[at] = merged;
  ++n;
  if (n > kMaxSpans) {
    // Closing the smallest gap adds the fewest samples.
    int best = 0;
    for (int i = 1; i + 1 < n; ++i)
      if (kept[i + 1].tIn - kept[i].tOut < kept[best + 1].tIn - kept[best].tOut) best = i;
    kept[best].tOut = std::max(kept[best].tOut, kept[best + 1].tOut);
    for (int i = best + 1; i + 1 < n; ++i) kept[i] = kept[i + 1];
    --n;
    ++stats_.spanMerges;
  }
  for (int i = 0; i < n; ++i) e.s[i] = kept[i];
  e.n = static_cast<std::uint8_t>(n);
}

void DBuffer::addBox(const WorldBox& box) {
  PP5_CHECK(!slot_.empty());
  if (box.empty()) return;
  ++stats_.boxes;
  const Camera& cam = rays_.camera();
  const bool persp = rays_.perspective();
  const int W = rays_.width(), H = rays_.height();

  Vec3 corner[8];
  for (int i = 0; i < 8; ++i) {
    const Vec3 w((i & 1) ? box.hi.x : box.lo.x, (i & 2) ? box.hi.y : box.lo.y, (i & 4) ? box.hi.z : box.lo.z);
    corner[i] = rays_.toCamera(w);
  }
  // Perspective: a plane this close to the eye keeps projected coordinates
  // finite; the rays' parts in front of it are shorter than any tolerance.
  // Orthographic: rays start on the eye's plane, t >= 0 is z >= 0.
  const double zNear =
      persp ? 1e-7 * (glm::length(box.hi - box.lo) + glm::length(0.5 * (box.lo + box.hi) - cam.eye)) : 0.0;

  Poly polys[6];
  int np = 0;
  double xmin = kInf, xmax = -kInf, ymin = kInf, ymax = -kInf;
  for (int a = 0; a < 3; ++a) {
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    for (int side = 0; side < 2; ++side) {
      // Outward normal (side ? +1 : -1) along axis a. Front: the eye (or, for
      // an orthographic view, the direction it looks from) is outside the face.
      double facing;
      if (persp) {
        const double plane = side ? box.hi[a] : box.lo[a];
        facing = side ? cam.eye[a] - plane : plane - cam.eye[a];
      } else {
        facing = side ? -rays_.forward()[a] : rays_.forward()[a];
      }
      if (facing == 0.0) continue;  // edge-on: covers no area
      Vec3 quad[4];
      const int order[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
      for (int q = 0; q < 4; ++q)
        quad[q] = corner[(side << a) | (order[q][0] << b) | (order[q][1] << c)];
      Vec3 clipped[5];
      const int n = clipNear(quad, zNear, clipped);
      if (n < 3) continue;
      Poly& p = polys[np++];
      p.n = n;
      p.id = static_cast<std::uint8_t>(1 + 2 * a + side) | (facing > 0.0 ? 0x80 : 0);
      for (int i = 0; i < n; ++i) {
        p.v[i] = rays_.toPixel(clipped[i]);
        xmin = std::min(xmin, p.v[i].x);
        xmax = std::max(xmax, p.v[i].x);
        ymin = std::min(ymin, p.v[i].y);
        ymax = std::max(ymax, p.v[i].y);
      }
    }
  }
  if (np == 0) return;
  // Bounds in pixels, clamped to the image before converting to int: near
  // clipping can leave coordinates far outside it.
  const double x0d = std::clamp(firstCentre(xmin), 0.0, static_cast<double>(W));
  const double x1d = std::clamp(firstCentre(xmax), 0.0, static_cast<double>(W));
  const double y0d = std::clamp(firstCentre(ymin), 0.0, static_cast<double>(H));
  const double y1d = std::clamp(firstCentre(ymax), 0.0, static_cast<double>(H));
  if (!(x0d < x1d) || !(y0d < y1d)) return;
  const int bx0 = static_cast<int>(x0d), bx1 = static_cast<int>(x1d);  // [bx0, bx1)
  const int by0 = static_cast<int>(y0d), by1 = static_cast<int>(y1d);
  const int bw = bx1 - bx0, bh = by1 - by0;
  const std::size_t area = static_cast<std::size_t>(bw) * static_cast<std::size_t>(bh);
  front_.assign(area, 0);
  back_.assign(area, 0);

  for (int f = 0; f < np; ++f) {
    const Poly& p = polys[f];
    std::vector<std::uint8_t>& dst = (p.id & 0x80) ? front_ : back_;
    const std::uint8_t id = p.id & 0x7f;
    double pymin = kInf, pymax = -kInf;
    for (int i = 0; i < p.n; ++i) {
      pymin = std::min(pymin, p.v[i].y);
      pymax = std::max(pymax, p.v[i].y);
    }
    const int j0 = static_cast<int>(std::clamp(firstCentre(pymin), y0d, y1d));
    const int j1 = static_cast<int>(std::clamp(firstCentre(pymax), y0d, y1d));
    // The edges that are not horizontal, each from its lower end: x at a
    // scanline is the lower end's x plus the slope times the height above
    // it. Two faces that share an edge have the same ends, so the same x.
    struct Edge {
      double ylo, yhi, xlo, slope;
    };
    Edge edges[5];
    int ne = 0;
    for (int i = 0; i < p.n; ++i) {
      glm::dvec2 lo = p.v[i], hi = p.v[i + 1 < p.n ? i + 1 : 0];
      if (lo.y == hi.y) continue;
      if (lo.y > hi.y) std::swap(lo, hi);
      edges[ne++] = {lo.y, hi.y, lo.x, (hi.x - lo.x) / (hi.y - lo.y)};
    }
    for (int j = j0; j < j1; ++j) {
      const double cy = j + 0.5;
      double xl = kInf, xr = -kInf;
      for (int e = 0; e < ne; ++e) {
        const Edge& g = edges[e];
        if (cy < g.ylo || cy >= g.yhi) continue;
        const double x = g.xlo + (cy - g.ylo) * g.slope;
        xl = std::min(xl, x);
        xr = std::max(xr, x);
      }
      if (!(xl < xr)) continue;
      const int i0 = static_cast<int>(std::clamp(firstCentre(xl), x0d, x1d));
      const int i1 = static_cast<int>(std::clamp(firstCentre(xr), x0d, x1d));
      if (i0 >= i1) continue;
      std::memset(dst.data() + static_cast<std::size_t>(j - by0) * bw + (i0 - bx0), id,
                  static_cast<std::size_t>(i1 - i0));
      stats_.facePixels += static_cast<std::uint64_t>(i1 - i0);
    }
  }

  const bool eyeInside = persp && cam.eye.x >= box.lo.x && cam.eye.x <= box.hi.x && cam.eye.y >= box.lo.y &&
                         cam.eye.y <= box.hi.y && cam.eye.z >= box.lo.z && cam.eye.z <= box.hi.z;
  // t where the pixel's ray meets the face's plane; NaN when it runs along it.
  auto faceT = [&](const Ray& r, std::uint8_t id) {
    const int a = (id - 1) >> 1;
    const double plane = ((id - 1) & 1) ? box.hi[a] : box.lo[a];
    return r.dir[a] != 0.0 ? (plane - r.origin[a]) / r.dir[a] : std::numeric_limits<double>::quiet_NaN();
  };
  for (int j = 0; j < bh; ++j) {
    const std::uint8_t* fr = front_.data() + static_cast<std::size_t>(j) * bw;
    const std::uint8_t* bk = back_.data() + static_cast<std::size_t>(j) * bw;
    const Vec3* dirs = persp ? rowDirs(by0 + j, bx0, bx1) : nullptr;
    int firstX = INT_MAX, lastX = -1;  // this row's inserted pixels
    for (int i = 0; i < bw; ++i) {
      if ((fr[i] | bk[i]) == 0) continue;
      const int x = bx0 + i, y = by0 + j;
      const std::uint32_t pixel = static_cast<std::uint32_t>(y) * static_cast<std::uint32_t>(W) + static_cast<std::uint32_t>(x);
      const Ray r = persp ? Ray{cam.eye, dirs[x]} : rays_.ray(x, y);
      double tIn = fr[i] ? faceT(r, fr[i]) : 0.0;
      double tOut = bk[i] ? faceT(r, bk[i]) : kInf;
      const bool grazing = std::isnan(tIn) || std::isnan(tOut);
      if (!fr[i]) ++stats_.startsInside;
      if (!bk[i]) ++stats_.frontOnly;
      // The rare pixels that see one kind of face only away from the near plane
      // (edge rounding), and grazing rays, take the exact ray-box test.
      if (grazing || !bk[i] || (!fr[i] && !eyeInside)) {
        double e0, e1;
        if (!intersectBox(r, box.lo, box.hi, e0, e1)) continue;
        if (!fr[i] || std::isnan(tIn)) tIn = eyeInside ? 0.0 : e0;
        if (!bk[i] || std::isnan(tOut)) tOut = e1;
      }
      tIn = std::max(tIn, 0.0);
      if (!(tOut >= tIn)) continue;
      ++stats_.boxPixels;
      insert(pixel, tIn, tOut);
      firstX = std::min(firstX, x);
      lastX = x;
    }
    if (lastX >= 0) {
      const auto y = static_cast<std::size_t>(by0 + j);
      rowLo_[y] = std::min(rowLo_[y], firstX);
      rowHi_[y] = std::max(rowHi_[y], lastX);
    }
  }
}

}  // namespace pp5::gp
