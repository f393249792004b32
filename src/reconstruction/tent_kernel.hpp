#pragma once
// The tent kernel's in-plane machinery (the notes at the top of
// reconstruction/splat_tent.cpp): the pixels a slice splats, the knot lattice of the
// rows' lateral profiles, the profiles themselves and the axial window, and
// the in-plane sums a voxel reads from them. Internal to the tent
// reconstructor; header-only so that its voxel loops inline them.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/frame.hpp"
#include "reconstruction/fan_mask.hpp"
#include "core/simd.hpp"

namespace pp5::gp::tent {

using F4 = simd::Float4;

// ---------------------------------------------------------------- pixels --

// The pixels of one slice that take part, as floats. `value` holds the value
// of selected pixels and 0 for rejected ones; `mask` (1/0) exists only when
// some pixel inside the rectangle is rejected.
struct SliceImage {
  int width = 0;
  int height = 0;
  int x0 = 0, y0 = 0, x1 = -1, y1 = -1;  // selection rectangle, inclusive
  std::vector<float> value;              // width * height, row-major
  std::vector<float> mask;               // empty = every pixel in the rectangle is selected
  std::uint64_t selected = 0;
  bool masked() const { return !mask.empty(); }
};

// The pixels the pixel methods would insert (PLUS's clip rectangle and fan,
// see fan_mask.hpp), less those darker than the rejection threshold (as PLUS
// rejects them). The rectangle is the bounding box of the pixels kept.
inline void selectPixels(const Frame& f, const std::vector<PixelRun>& runs, double rejectBelow, SliceImage& out) {
  out.width = f.width;
  out.height = f.height;
  const std::size_t n = static_cast<std::size_t>(f.width) * static_cast<std::size_t>(f.height);
  out.value.assign(n, 0.0f);
  out.mask.assign(n, 0.0f);
  out.selected = 0;
  out.x0 = f.width;
  out.y0 = f.height;
  out.x1 = -1;
  out.y1 = -1;
  const bool reject = rejectBelow >= 0.0;
  for (const PixelRun& run : runs) {
    const std::size_t row = static_cast<std::size_t>(run.y) * static_cast<std::size_t>(f.width);
    int first = -1, last = -1;  // the run's first and last pixel kept
    for (int c = run.x0; c <= run.x1; ++c) {
      const std::size_t i = row + static_cast<std::size_t>(c);
      const double v = f.pixelType == PixelType::U8 ? static_cast<double>(f.pixels[i]) : f.value(c, run.y);
      if (reject && v < rejectBelow) continue;
      out.value[i] = static_cast<float>(v);
      out.mask[i] = 1.0f;
      ++out.selected;
      if (first < 0) first = c;
      last = c;
    }
    if (first < 0) continue;
    out.x0 = std::min(out.x0, first);
    out.x1 = std::max(out.x1, last);
    out.y0 = std::min(out.y0, run.y);
    out.y1 = std::max(out.y1, run.y);
  }
  // No mask needed when every pixel of the rectangle is kept.
  if (out.selected > 0 && out.selected == static_cast<std::uint64_t>(out.x1 - out.x0 + 1) *
                                              static_cast<std::uint64_t>(out.y1 - out.y0 + 1))
    out.mask.clear();
}

// A fill-in slice's pixels between two slices' (see fillInCount), t of the
// way from `a` to `b`: values linearly, and a pixel takes part when it does
// in both; only the pixels of `box` (x0 y0 x1 y1, inside both selections).
// False when none takes part.
inline bool blendSlices(const SliceImage& a, const SliceImage& b, const std::array<int, 4>& box, double t,
                        SliceImage& out) {
  auto kept = [](const SliceImage& im, std::size_t i) { return !im.masked() || im.mask[i] > 0.0f; };
  const auto tb = static_cast<float>(t), ta = static_cast<float>(1.0 - t);
  out.width = b.width;
  out.height = b.height;
  const std::size_t npx = b.value.size();
  out.value.assign(npx, 0.0f);
  out.mask.assign(npx, 0.0f);
  out.selected = 0;
  const auto [x0, y0, x1, y1] = box;
  out.x0 = x1;
  out.y0 = y1;
  out.x1 = x0;
  out.y1 = y0;
  for (int r = y0; r <= y1; ++r)
    for (int c = x0; c <= x1; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(b.width) + static_cast<std::size_t>(c);
      if (!kept(a, i) || !kept(b, i)) continue;
      out.value[i] = ta * a.value[i] + tb * b.value[i];
      out.mask[i] = 1.0f;
      ++out.selected;
      out.x0 = std::min(out.x0, c);
      out.x1 = std::max(out.x1, c);
      out.y0 = std::min(out.y0, r);
      out.y1 = std::max(out.y1, r);
    }
  if (out.selected == 0) return false;
  if (out.selected == static_cast<std::uint64_t>(out.x1 - out.x0 + 1) * static_cast<std::uint64_t>(out.y1 - out.y0 + 1))
    out.mask.clear();
  return true;
}

// ----------------------------------------------------------------- kernel --

// The most pixels a kernel may span along either axis (checkPose refuses a
// pose whose pixels are smaller), and the axial window's chunks of four rows
// that allows (floor(2 ha / syv) + 1 rows).
inline constexpr int kMaxWindowPixels = 1024;
inline constexpr int kMaxWindowChunks = (kMaxWindowPixels + 1 + 3) / 4;

// std::clamp for doubles, as maxsd and minsd where there is SSE2 (std::clamp
// compiles to compares and branches, as it must keep the sign of a zero).
inline double clampD(double x, double lo, double hi) {
#if defined(__SSE2__)
  return _mm_cvtsd_f64(_mm_min_sd(_mm_max_sd(_mm_set_sd(x), _mm_set_sd(lo)), _mm_set_sd(hi)));
#else
  return std::clamp(x, lo, hi);
#endif
}

// floor() for values already clamped to (-2^20, 2^31), without a libm call
// (exact but within 2^-32 below an integer, where it may round up; a row of
// voxels then only gains or loses a voxel on the support's boundary, whose
// weight is of that order).
inline std::int64_t floorInt(double x) {
  constexpr std::int64_t kBias = std::int64_t{1} << 20;
  return static_cast<std::int64_t>(x + static_cast<double>(kBias)) - kBias;
}

// The knots of the lateral profiles (see the header comment): every pixel
// period c holds the knots c*sx + off[t], t = 0, 1, 2, with off[0] = 0 and
// {off[1], off[2]} = {hl mod sx, -hl mod sx}, where the tents of the pixels
// have their kinks; knot (c, t) has the index 3 * (c - cLo) + t. When hl is a
// multiple of sx (or of sx/2) some offsets coincide and their cells are
// empty: a voxel lands in one only by rounding, and then reads a knot's value.
struct KnotLattice {
  double sx = 1.0, invSx = 1.0;
  double off[3] = {0.0, 0.0, 0.0};
  int cLo = 0, cHi = 0;  // first and last period, a multiple of four of them
  int periods() const { return cHi - cLo + 1; }
  // For locating a voxel, in periods: the offsets / sx, 1 / (the cells'
  // widths / sx) (0 for an empty cell), and the last period a cell may start in.
  double offP[3] = {0.0, 0.0, 0.0};
  double invWidthP[3] = {0.0, 0.0, 0.0};
  double lastP = 0.0;
};

// Knots for the pixel columns x0..x1. The profiles vanish outside
// (x0*sx - hl, x1*sx + hl); the first and last periods lie wholly outside, so
// a voxel beyond them can be clamped into them and reads zeros.
inline KnotLattice knotLattice(double sx, double hl, int x0, int x1) {
  KnotLattice L;
  L.sx = sx;
  L.invSx = 1.0 / sx;
  const double a = std::fmod(hl, sx), b = a > 0.0 ? sx - a : 0.0;
  L.off[1] = std::min(a, b);
  L.off[2] = std::max(a, b);
  for (int t = 0; t < 3; ++t) {
    L.offP[t] = L.off[t] * L.invSx;
    const double w = (t < 2 ? L.off[t + 1] : sx) - L.off[t];
    L.invWidthP[t] = w > 0.0 ? sx / w : 0.0;
  }
  const int reach = static_cast<int>(std::ceil(hl * L.invSx));
  L.cLo = x0 - reach - 1;
  L.cHi = L.cLo + (x1 + reach + 1 - L.cLo) / 4 * 4 + 3;  // a multiple of four periods
  L.lastP = L.cHi - L.cLo - 1;                          // its cell's last knot is (cHi, 0)
  return L;
}

// The knot cell of lateral coordinate u: the index of its first knot, and
// where u lies between its two knots (0..1). Clamped to the lattice, and the
// fraction to its cell, so that a voxel always reads a convex combination of
// two knots: zero where both are zero, never negative.
inline int knotCell(const KnotLattice& L, double u, float& frac) {
  const double x = clampD(u * L.invSx - L.cLo, 0.0, L.lastP);  // periods from cLo
  const int c = static_cast<int>(x);                          // x >= 0: the floor
  const double g = x - c;                                     // within the period
  const int t = static_cast<int>(g >= L.offP[1]) + static_cast<int>(g >= L.offP[2]);
  frac = static_cast<float>(clampD((g - L.offP[t]) * L.invWidthP[t], 0.0, 1.0));
  return 3 * c + t;
}

// The pixels' lateral tent weights at the knots of one offset: pixel
// c - (j0 + i) weighs w[i] at knot (c, t), for every period c.
struct LatticeTaps {
  int j0 = 0;
  std::vector<float> w;
  int jEnd() const { return j0 + static_cast<int>(w.size()); }
};

inline LatticeTaps latticeTaps(const KnotLattice& L, double hl, int t) {
  const int reach = static_cast<int>(std::ceil(hl * L.invSx)) + 1;
  std::vector<float> w;
  for (int j = -reach; j <= reach; ++j) {
    const double x = 1.0 - std::abs(j * L.sx + L.off[t]) / hl;
    // A knot on one of a pixel's kinks (|distance| = hl) must get exactly 0
    // from it, whatever the rounding of the offsets, or voxels just outside
    // that pixel's support would get a weight of rounding size.
    w.push_back(x > 1e-9 ? static_cast<float>(x) : 0.0f);
  }
  // Only the nonzero run (a tent's support is an interval).
  const auto first = std::find_if(w.begin(), w.end(), [](float x) { return x > 0.0f; });
  const auto last = std::find_if(w.rbegin(), w.rend(), [](float x) { return x > 0.0f; }).base();
  LatticeTaps taps;
  if (first < last) {
    taps.j0 = -reach + static_cast<int>(first - w.begin());
    taps.w.assign(first, last);
  }
  return taps;
}

// One pixel row's profiles at every knot, interleaved as (P, M) pairs in knot
// order: P = sum over the row's pixels of tent_l * value, M = the same with
// the mask (1 for a selected pixel, else 0). Each knot's sum runs over its
// taps in a fixed order; four periods at a time.
class ProfileRow {
public:
  ProfileRow(const KnotLattice& L, double hl) : L_(L) {
    // The three offsets' taps over the union of their ranges (0 outside
    // their own), so that each pixel is loaded once for all three. Offset 0
    // always has taps (the pixel under the knot weighs 1); the others may
    // have none, when hl < sx.
    LatticeTaps taps[3];
    int jMin = 0, jMax = 1;
    for (int t = 0; t < 3; ++t) {
      taps[t] = latticeTaps(L, hl, t);
      if (taps[t].w.empty()) continue;
      jMin = std::min(jMin, taps[t].j0);
      jMax = std::max(jMax, taps[t].jEnd());
    }
    j0_ = jMin;
    for (int j = jMin; j < jMax; ++j) {
      Taps3& w = taps_.emplace_back();
      for (int t = 0; t < 3; ++t) {
        const int i = j - taps[t].j0;
        const bool in = i >= 0 && i < static_cast<int>(taps[t].w.size());
        w[t] = F4::set1(in ? taps[t].w[static_cast<std::size_t>(i)] : 0.0f);
      }
    }
    // Pixels pLo_ .. cHi - jMin cover every tap of every knot.
    pLo_ = L.cLo - jMax;
    const auto span = static_cast<std::size_t>(L.cHi - jMin - pLo_ + 1);
    val_.assign(span, 0.0f);
    msk_.assign(span, 0.0f);
    maskSums_.assign(3 * static_cast<std::size_t>(L.periods()), 0.0f);
  }

  // Row r of img into out (6 * periods floats). Without a mask the rectangle
  // is the same on every row, and so is M: it is summed for the first row only.
  void build(const SliceImage& img, int r, float* out) {
    const std::size_t src =
        static_cast<std::size_t>(r) * static_cast<std::size_t>(img.width) + static_cast<std::size_t>(img.x0);
    const auto dst = static_cast<std::size_t>(img.x0 - pLo_);
    const auto n = static_cast<std::size_t>(img.x1 - img.x0 + 1);
    std::copy_n(img.value.data() + src, n, val_.data() + dst);
    const bool sumMask = img.masked() || !haveMaskSums_;
    if (img.masked())
      std::copy_n(img.mask.data() + src, n, msk_.data() + dst);
    else
      std::fill_n(msk_.data() + dst, n, 1.0f);
    const auto periods = static_cast<std::size_t>(L_.periods());
    for (int c = 0; c < L_.periods(); c += 4, out += 24) {
      F4 P[3], M[3];
      convolve(val_.data(), c, P);
      if (sumMask) convolve(msk_.data(), c, M);
      for (int t = 0; t < 3; ++t) {
        float* m = maskSums_.data() + static_cast<std::size_t>(t) * periods + static_cast<std::size_t>(c);
        if (sumMask)
          M[t].store(m);
        else
          M[t] = F4::load(m);
      }
      storeInterleaved(P, M, out);
    }
    haveMaskSums_ = true;
  }

private:
  // sum[t] = sum_i taps_[i][t] * pixel(cLo + c + l - j0 - i) for the periods
  // c + l, l = 0..3 (counted from cLo).
  void convolve(const float* pixels, int c, F4 (&sum)[3]) const {
    const float* p = pixels + (L_.cLo + c - j0_ - pLo_);
    F4 a0 = F4::zero(), a1 = F4::zero(), a2 = F4::zero();
    for (const Taps3& w : taps_) {
      const F4 x = F4::load(p--);
      a0 = a0 + w[0] * x;
      a1 = a1 + w[1] * x;
      a2 = a2 + w[2] * x;
    }
    sum[0] = a0;
    sum[1] = a1;
    sum[2] = a2;
  }

  // P[t] and M[t] of four periods as (P, M) pairs in knot order: period by
  // period, offset by offset.
  static void storeInterleaved(const F4 (&P)[3], const F4 (&M)[3], float* out) {
    F4 lo[3], hi[3];  // (P, M) of periods 0 and 1, and of periods 2 and 3
    for (int t = 0; t < 3; ++t) F4::interleave(P[t], M[t], lo[t], hi[t]);
    for (const F4* h : {lo, hi}) {
      F4::halves(h[0], h[1]).store(out);                          // period 0 (2): offsets 0, 1
      F4::halves(h[2], F4::high(h[0])).store(out + 4);            // offset 2; period 1 (3): offset 0
      F4::halves(F4::high(h[1]), F4::high(h[2])).store(out + 8);  // period 1 (3): offsets 1, 2
      out += 12;
    }
  }

  using Taps3 = std::array<F4, 3>;
  KnotLattice L_;
  int j0_ = 0;
  std::vector<Taps3> taps_;  // pixel c - (j0 + i) weighs taps_[i][t] at knot (c, t), in every lane
  int pLo_ = 0;
  std::vector<float> val_, msk_;  // one row, zero outside the rectangle
  std::vector<float> maskSums_;   // M for offsets 0, 1, 2 (planar)
  bool haveMaskSums_ = false;
};

// Everything the per-voxel sum needs about one slice: the knots, the
// profiles of the selected rows and of zero rows above and below them (a
// voxel's axial window always lies inside), and the axial kernel.
struct SliceKernel {
  KnotLattice lat;
  double ha, syv, invSyv, eyu, invHe;
  float invHaF;
  int y0, y1;           // selected rows
  int rows;             // axial window: every row that can be within ha of a voxel,
  int chunks;           //   rounded up to chunks of four
  int oy;               // pixel row of the first profile row
  double firstBase, firstLo, firstHi;  // for axialWindow
  std::size_t stride;   // floats per profile row
  const float* prof;
  const float* rowOff;  // 4 * chunks: rr * syv, +infinity for rows past `rows`
};

// A voxel's axial window: the profile rows r0 .. r0 + 4 * chunks - 1 and
// their tent weights, four to an F4. A row beyond the kernel gets the weight
// 0 and adds exactly +0, so the window has a fixed number of rows.
struct Axial {
  int r0 = 0;
  std::size_t row0 = 0;  // offset of row r0's profile
  F4* tv = nullptr;      // K.chunks
};

inline void axialWindow(const SliceKernel& K, double V, Axial& a) {
  // The first row strictly inside |V - r*syv| < ha, counted from oy, and
  // clamped so the window stays inside the padding (a clamped window holds
  // no selected pixel).
  const double first = clampD((V - K.ha) * K.invSyv + K.firstBase, K.firstLo, K.firstHi);
  const int idx = static_cast<int>(first);  // first >= 0: the floor
  a.r0 = K.oy + idx;
  const F4 dv0 = F4::set1(static_cast<float>(V - a.r0 * K.syv));  // from pixel row r0
  for (int q = 0; q < K.chunks; ++q)
    a.tv[q] = F4::max0(F4::set1(1.0f) - F4::abs(dv0 - F4::load(K.rowOff + 4 * q)) * F4::set1(K.invHaF));
  a.row0 = static_cast<std::size_t>(idx) * K.stride;
}

// The slice's in-plane sums at lateral coordinate U with the axial window
// `ax`: sw = sum over pixels of tent_l * tent_a * mask, swv = the same times
// the value.
template <bool Sheared>
inline void inPlaneSums(const SliceKernel& K, const Axial& ax, double U, float& sw, float& swv) {
  const float* p = K.prof + ax.row0;
  const std::size_t stride = K.stride;
  F4 a = F4::zero();
  if constexpr (!Sheared) {
    // Every row has its kinks at the same knots: sum the rows' (P, M) at the
    // cell's two knots, then interpolate once.
    float frac;
    p += 2 * knotCell(K.lat, U, frac);
    int q = 0;
    do {
      const F4 t = ax.tv[q];
      a = a + F4::lane<0>(t) * F4::load(p);
      a = a + F4::lane<1>(t) * F4::load(p + stride);
      a = a + F4::lane<2>(t) * F4::load(p + 2 * stride);
      a = a + F4::lane<3>(t) * F4::load(p + 3 * stride);
      p += 4 * stride;
    } while (++q < K.chunks);
    a = a + F4::set1(frac) * (F4::high(a) - a);
  } else {
    // Row r's pixels sit r*eyu further along u: each row has its own cell.
    // A calibration's shear moves the rows by a fraction of a pixel over
    // the window, so its first and last rows usually share one cell; then
    // every row between does (the cell moves monotonically with r). Otherwise
    // the window is cut into bands of rows that share a cell, halving until a
    // band's ends agree. In a band a row's fraction is affine in r, fa + l*phi
    // for its l-th row, so the band needs only the sums of tv*X and of l*tv*X
    // at the cell's two knots: the same sum as row by row, up to rounding.
    const int lastRow = 4 * K.chunks - 1;
    alignas(16) float tv[4 * kMaxWindowChunks];  // the window's axial weights
    for (int q = 0; q < K.chunks; ++q) ax.tv[q].store(tv + 4 * q);
    auto cellAt = [&](int l, float& f) { return knotCell(K.lat, U - (ax.r0 + l) * K.eyu, f); };
    auto band = [&](int l0, int l1, int k, float fa, float fb) {
      const float* q = p + static_cast<std::size_t>(l0) * stride + 2 * k;
      F4 ba = F4::zero(), bb = F4::zero();
      for (int l = l0; l <= l1; ++l, q += stride) {
        const F4 x = F4::load(q);
        ba = ba + F4::set1(tv[l]) * x;
        bb = bb + F4::set1(static_cast<float>(l - l0) * tv[l]) * x;
      }
      const float phi = l1 > l0 ? (fb - fa) / static_cast<float>(l1 - l0) : 0.0f;
      a = a + ba + F4::set1(fa) * (F4::high(ba) - ba) + F4::set1(phi) * (F4::high(bb) - bb);
    };
    auto split = [&](auto& self, int l0, int l1, int ka, float fa, int kb, float fb) -> void {
      if (ka == kb) return band(l0, l1, ka, fa, fb);
      if (l1 == l0 + 1) {
        band(l0, l0, ka, fa, fa);
        band(l1, l1, kb, fb, fb);
        return;
      }
      const int mid = l0 + (l1 - l0) / 2;
      float fm, fn;
      const int km = cellAt(mid, fm), kn = cellAt(mid + 1, fn);
      self(self, l0, mid, ka, fa, km, fm);
      self(self, mid + 1, l1, kn, fn, kb, fb);
    };
    float f0, f1;
    const int k0 = cellAt(0, f0), k1 = cellAt(lastRow, f1);
    split(split, 0, lastRow, k0, f0, k1, f1);
  }
  swv = a.lane0();
  sw = a.lane1();
}

// The in-plane sums from the profiles, as contributeRows reads them: axial(V)
// sets the axial window, inPlane(U) sums it at lateral coordinate U. Each
// thread works on its own copy (the window's weights are scratch).
template <bool Sheared>
class KnotSums {
public:
  explicit KnotSums(const SliceKernel& K) : K_(K), tv_(static_cast<std::size_t>(K.chunks)) { ax_.tv = tv_.data(); }
  KnotSums(const KnotSums& o) : K_(o.K_), ax_(o.ax_), tv_(o.tv_) { ax_.tv = tv_.data(); }
  KnotSums& operator=(const KnotSums&) = delete;
  void axial(double V) { axialWindow(K_, V, ax_); }
  void inPlane(double U, float& sw, float& swv) const { inPlaneSums<Sheared>(K_, ax_, U, sw, swv); }

private:
  SliceKernel K_;  // a copy: the compiler cannot tell that the voxel stores leave it alone
  Axial ax_;
  std::vector<F4> tv_;
};

// How the slice coordinates change along a row of voxels (grid x). ConstV: V
// stays the same (the image's axial axis is perpendicular to grid x, as on
// the paper's arm, which keeps the probe vertical), so the axial window is
// computed once per row. ConstUV: U does too (the row runs along the slice's
// normal), so the whole in-plane sum is. Both give the same bits as Any.

}  // namespace pp5::gp::tent
