#include "gp/pixel_kernels.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.hpp"
#include "core/simd.hpp"

namespace pp5::gp::pixel {

namespace {

// The voxels a row writes, appended to its slab's list the first time only,
// without a branch (room for `extra` entries is made first). Kept in locals
// while the row is walked and handed back at its end.
class RowWrites {
public:
  RowWrites(const Job& job, SlabOut& so, std::size_t extra) : so_(so), touched_(job.touched), bx_(job.bx), bxy_(job.bxy) {
    so.reserveWritten(extra);
    idx_ = so.written.data();
    brick_ = so.writtenBrick.data();
    n_ = so.nWritten;
  }
  ~RowWrites() { so_.nWritten = n_; }
  RowWrites(const RowWrites&) = delete;
  RowWrites& operator=(const RowWrites&) = delete;
  // Brick coordinates times their strides, per axis.
  std::int64_t bx(std::int64_t x) const { return x >> 4; }
  std::int64_t by(std::int64_t y) const { return (y >> 4) * bx_; }
  std::int64_t bz(std::int64_t z) const { return (z >> 4) * bxy_; }
  void add(std::int64_t i, std::int64_t brick) {
    idx_[n_] = i;
    brick_[n_] = static_cast<std::uint32_t>(brick);
    n_ += touched_[i] == 0;
    touched_[i] = 1;
  }
  void add(std::int64_t i, std::int64_t x, std::int64_t y, std::int64_t z) { add(i, bx(x) + by(y) + bz(z)); }

private:
  SlabOut& so_;
  std::uint8_t* touched_;
  std::int64_t bx_, bxy_;
  std::int64_t* idx_ = nullptr;
  std::uint32_t* brick_ = nullptr;
  std::size_t n_ = 0;
};

template <class Pix>
const Pix* rowPtr(const Job& job, int y) {
  return reinterpret_cast<const Pix*>(job.pixels) + static_cast<std::size_t>(y) * static_cast<std::size_t>(job.width);
}

// Columns of [x0, x1] whose slab-axis coordinate b + i*g can fall in [pa, pb).
// A superset (two columns of margin): the kernels test every pixel exactly, so
// this only saves work and never decides anything.
void columnRange(double b, double g, double pa, double pb, int x0, int x1, int& ia, int& ib) {
  ia = x0;
  ib = x1;
  if (!(std::abs(g) > 1e-9)) return;  // the row runs along the slab
  double t0 = (pa - b) / g, t1 = (pb - b) / g;
  if (t0 > t1) std::swap(t0, t1);
  const double lo = std::floor(t0) - 2.0, hi = std::ceil(t1) + 2.0;
  if (lo > x0) ia = lo > x1 ? x1 + 1 : static_cast<int>(lo);
  if (hi < x1) ib = hi < x0 ? x0 - 1 : static_cast<int>(hi);
}

// Per-axis bounds of the voxels a thread may write: the grid, except its slab
// along the split axis.
struct Bounds {
  std::int64_t lo[3], hi[3];
  Bounds(const Job& job, const Slab& s) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = 0;
      hi[a] = job.dims[a];
    }
    lo[s.axis] = s.lo;
    hi[s.axis] = s.hi;
  }
  bool owns(int a, std::int64_t n) const { return n >= lo[a] && n < hi[a]; }
};

// ---------------------------------------------------------------------------
// Float positions carry this offset, so that truncation toward zero is floor
// for every coordinate that matters (>= -1), and one unsigned compare per axis
// tests the bounds. Positions keep a resolution of 2^-32 voxel.
constexpr double kOffset = 1048576.0;
constexpr std::int64_t kOffsetI = std::int64_t{1} << 20;

// ---------------------------------------------------------------------------
// Walking a run voxel by voxel (see the top of the file).

// Float rows: p(i) = b + i*X in offset voxel units. The voxel coordinate of
// column i is decided by the columns where the row crosses integers: integer c
// is crossed at column ceil((c - b) / X) when X > 0 (the first column with
// p >= c) and at floor((c - b) / X) + 1 when X < 0 (the first with p < c).
// That is floor(p(i)) up to double rounding, monotonic by construction, and it
// cuts a run into voxel segments with a few operations per segment. A row
// that moves less than 1e-12 voxel per pixel along an axis stays in floor(b).
struct FloatStep {
  double b = 0, X = 0, invX = 0;
  int dir = 0;           // sign of X
  std::int64_t m = 0;    // voxel coordinate (offset) of the current segment
  int t = 0;             // first column past it
  FloatStep() = default;
  FloatStep(double b0, double x) : b(b0), X(x) {
    if (std::abs(x) > 1e-12) {
      invX = 1.0 / x;
      dir = x > 0 ? 1 : -1;
    }
  }
  // The first column past voxel mm, in the direction of the walk.
  int exit(std::int64_t mm) const {
    if (dir == 0) return std::numeric_limits<int>::max();
    double r = (double(dir > 0 ? mm + 1 : mm) - b) * invX;
    r = std::min(std::max(r, -1e9), 1e9);
    const int c = static_cast<int>(r);
    return dir > 0 ? c + (double(c) < r) : c - (double(c) > r) + 1;
  }
  void start(int i0) {
    if (dir == 0) {
      m = static_cast<std::int64_t>(b);
      t = exit(m);
      return;
    }
    m = static_cast<std::int64_t>(b + double(i0) * X);
    if (dir > 0) {
      while (exit(m) <= i0) ++m;
      while (exit(m - 1) > i0) --m;
    } else {
      while (exit(m) <= i0) --m;
      while (exit(m + 1) > i0) ++m;
    }
    t = exit(m);
  }
  // (A branch here is cheaper than computing every axis's exit branch-free:
  // the predictor learns the row's stepping pattern.)
  void advance(int e) {
    if (t != e) return;
    m += dir;
    t = exit(m);
  }
};

// pre[k] = px[0] + ... + px[k-1] for k = 0 .. len (exact for len < 2^24).
// Sixteen pixels at a time: a serial running sum costs a dependent add and a
// store per pixel, which a segment of five pixels cannot hide.
inline void prefixSumsU8(const std::uint8_t* px, int len, std::uint32_t* pre) {
  pre[0] = 0;
  std::uint32_t carry = 0;
  int k = 0;
#if defined(__SSE2__)
  const __m128i zero = _mm_setzero_si128();
  for (; k + 16 <= len; k += 16) {
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(px + k));
    // Inclusive sums within each half, in 16-bit lanes (at most 16 * 255).
    __m128i lo = _mm_unpacklo_epi8(v, zero), hi = _mm_unpackhi_epi8(v, zero);
    lo = _mm_add_epi16(lo, _mm_slli_si128(lo, 2));
    hi = _mm_add_epi16(hi, _mm_slli_si128(hi, 2));
    lo = _mm_add_epi16(lo, _mm_slli_si128(lo, 4));
    hi = _mm_add_epi16(hi, _mm_slli_si128(hi, 4));
    lo = _mm_add_epi16(lo, _mm_slli_si128(lo, 8));
    hi = _mm_add_epi16(hi, _mm_slli_si128(hi, 8));
    const __m128i loTotal = _mm_shufflehi_epi16(lo, 0xff);  // lanes 4..7 = lane 7
    hi = _mm_add_epi16(hi, _mm_unpackhi_epi64(loTotal, loTotal));
    const __m128i c = _mm_set1_epi32(static_cast<int>(carry));
    std::uint32_t* out = pre + k + 1;
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out), _mm_add_epi32(_mm_unpacklo_epi16(lo, zero), c));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + 4), _mm_add_epi32(_mm_unpackhi_epi16(lo, zero), c));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + 8), _mm_add_epi32(_mm_unpacklo_epi16(hi, zero), c));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + 12), _mm_add_epi32(_mm_unpackhi_epi16(hi, zero), c));
    carry += static_cast<std::uint32_t>(_mm_extract_epi16(hi, 7));
  }
#endif
  for (; k < len; ++k) pre[k + 1] = carry += px[k];
}

// Bit k set where byte p[k] is not zero (k < 16).
inline std::uint32_t nonZeroBytes16(const std::uint8_t* p) {
#if defined(__SSE2__)
  const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p));
  return ~static_cast<std::uint32_t>(_mm_movemask_epi8(_mm_cmpeq_epi8(v, _mm_setzero_si128()))) & 0xffffu;
#else
  std::uint32_t bits = 0;
  for (int k = 0; k < 16; ++k) bits |= static_cast<std::uint32_t>(p[k] != 0) << k;
  return bits;
#endif
}

// Calls seg(i, e, mx, my, mz) for each non-empty column range [i, e) of
// [ia, ib] in voxel (mx, my, mz) (offset coordinates). The same segments as
// stepping from voxel to voxel and comparing the three axes' exits, but
// without its branches, which the predictor cannot learn when several pixels
// share a voxel: where each axis steps is marked first (one bit per axis in
// `marks`, a zeroed scratch of at least ib - ia + 17 bytes, zeroed again on
// return), and the marked columns are then found 16 at a time. That needs at
// most one step per axis per column, |X| < 1; coarser rows take the walk.
template <class Seg>
void walkRunFloat(FloatStep (&st)[3], int ia, int ib, std::uint8_t* marks, Seg&& seg) {
  if (ia > ib) return;
  for (FloatStep& s : st) s.start(ia);
  if (!(std::abs(st[0].X) < 0.9 && std::abs(st[1].X) < 0.9 && std::abs(st[2].X) < 0.9)) {
    int i = ia;
    for (;;) {
      const int e = std::min(std::min(st[0].t, st[1].t), std::min(st[2].t, ib + 1));
      if (e > i) seg(i, e, st[0].m, st[1].m, st[2].m);
      if (e > ib) return;
      for (FloatStep& s : st) s.advance(e);
      i = e;
    }
  }
  // start() leaves each axis's first step after ia.
  for (int a = 0; a < 3; ++a) {
    const FloatStep& s = st[a];
    std::int64_t m = s.m;
    for (int t = s.t; t <= ib; t = s.exit(m)) {
      marks[t - ia] |= static_cast<std::uint8_t>(1u << a);
      m += s.dir;
    }
  }
  std::int64_t m0 = st[0].m, m1 = st[1].m, m2 = st[2].m;
  const std::int64_t d0 = st[0].dir, d1 = st[1].dir, d2 = st[2].dir;
  const int len = ib - ia + 1;
  int i = 0;
  for (int base = 0; base < len; base += 16) {
    std::uint32_t bits = nonZeroBytes16(marks + base);
    while (bits) {
      const int k = base + std::countr_zero(bits);
      bits &= bits - 1;
      seg(ia + i, ia + k, m0, m1, m2);
      const std::uint8_t mk = marks[k];
      marks[k] = 0;
      m0 += d0 & -static_cast<std::int64_t>(mk & 1u);
      m1 += d1 & -static_cast<std::int64_t>((mk >> 1) & 1u);
      m2 += d2 & -static_cast<std::int64_t>((mk >> 2) & 1u);
      i = k;
    }
  }
  seg(ia + i, ib + 1, m0, m1, m2);
}

// Fixed rows (plus): q(i) = floor((b + i*X) / 2^14), PLUS's own per-pixel
// formula. Where q steps is guessed in double and then settled with the exact
// integer formula, so the segments are exactly PLUS's voxels.
struct FixedAxis {
  std::int64_t b = 0, X = 0;
  double invX = 0;
  FixedAxis() = default;
  FixedAxis(std::int64_t b0, std::int64_t x) : b(b0), X(x), invX(x != 0 ? 1.0 / double(x) : 0.0) {}
  bool flat() const { return X == 0; }
  std::int64_t q(int i) const { return (b + std::int64_t{i} * X) >> plusmath::kFracBits; }
  double guess(std::int64_t qi) const {
    return (double((X > 0 ? qi + 1 : qi) * plusmath::kOne) - double(b)) * invX;
  }
};

// The first column after i (at most limit + 1) where ax.q differs from qi.
template <class Axis>
[[gnu::always_inline]] inline int nextStep(const Axis& ax, int i, std::int64_t qi, int limit) {
  if (ax.flat()) return limit + 1;
  const double g = ax.guess(qi);
  int e = i + 1;
  if (g >= double(limit + 1))
    e = limit + 1;
  else if (g > double(i + 1))
    e = static_cast<int>(g) + 1;  // ceil, or one more: the corrections below settle it
  while (e - 1 > i && ax.q(e - 1) != qi) --e;
  while (e <= limit && ax.q(e) == qi) ++e;
  return e;
}

// Calls seg(i, e, q) for each maximal column range [i, e) of [ia, ib] whose
// pixels share the voxel q[3].
template <class Axis, class Seg>
void walkRun(const Axis (&ax)[3], int ia, int ib, Seg&& seg) {
  if (ia > ib) return;
  std::int64_t q[3];
  int t[3];
  for (int a = 0; a < 3; ++a) {
    q[a] = ax[a].q(ia);
    t[a] = nextStep(ax[a], ia, q[a], ib);
  }
  int i = ia;
  for (;;) {
    const int e = std::min(t[0], std::min(t[1], t[2]));
    seg(i, e, q);
    if (e > ib) return;
    for (int a = 0; a < 3; ++a)
      if (t[a] == e) {
        q[a] = ax[a].q(e);
        t[a] = nextStep(ax[a], e, q[a], ib);
      }
    i = e;
  }
}

// ---------------------------------------------------------------------------
// Nearest neighbour: the pixels of one segment are one voxel's, so the
// segment's update is gathered in registers and the voxel written once.

template <class Pix, Compounding C>
void nearestFloat(const Job& job, FloatCell* cells, const Slab& slab, bool split, SlabOut& out) {
  const Bounds bd(job, slab);
  const std::int64_t sy = job.sy, sz = job.sz;
  const int rej = job.rejectBelow;
  std::int64_t off[3];
  std::uint64_t range[3];
  for (int a = 0; a < 3; ++a) {
    off[a] = kOffsetI + bd.lo[a];
    range[a] = static_cast<std::uint64_t>(bd.hi[a] - bd.lo[a]);
  }
  std::uint64_t inserted = 0;
  for (const PixelRun& r : *job.runs) {
    const Pix* row = rowPtr<Pix>(job, r.y);
    FloatStep st[3];
    for (int a = 0; a < 3; ++a)
      st[a] = FloatStep(job.map.O[a] + double(r.y) * job.map.Y[a] + (0.5 + kOffset), job.map.X[a]);
    int ia = r.x0, ib = r.x1;
    if (split) {
      const int a = slab.axis;
      columnRange(st[a].b, st[a].X, kOffset + double(bd.lo[a]), kOffset + double(bd.hi[a]), r.x0, r.x1, ia, ib);
    }
    if (ia > ib) continue;
    RowWrites wr(job, out, static_cast<std::size_t>(ib - ia + 1));  // a voxel per segment at most
    // MEAN: a segment's sum and count from prefix sums, without a loop whose
    // length the branch predictor cannot guess.
    // (pre[k - ia]: sum of the pixels ia .. k-1)
    std::uint64_t* pre = out.prefix.data();
    std::uint32_t* pre32 = out.prefix32.data();  // 8-bit pixels, no rejection
    std::uint32_t* cnt = out.count.data();
    constexpr bool kBytes = sizeof(Pix) == 1;
    if constexpr (C == Compounding::Mean) {
      std::uint64_t sum = 0;
      pre[0] = 0;
      const int len = ib - ia + 1;
      const Pix* px = row + ia;
      if (kBytes && rej <= 0) {
        prefixSumsU8(reinterpret_cast<const std::uint8_t*>(px), len, pre32);
      } else if (rej <= 0) {
        for (int k = 0; k < len; ++k) pre[k + 1] = sum += px[k];
      } else {
        std::uint32_t n = 0;
        cnt[0] = 0;
        for (int k = 0; k < len; ++k) {
          const int p = px[k];
          const bool ok = p >= rej;
          pre[k + 1] = sum += ok ? static_cast<std::uint64_t>(p) : 0u;
          cnt[k + 1] = n += ok;
        }
      }
    }
    walkRunFloat(st, ia, ib, out.marks.data(), [&](int i, int e, std::int64_t mx, std::int64_t my, std::int64_t mz) {
      const std::int64_t ux = mx - off[0], uy = my - off[1], uz = mz - off[2];
      if ((static_cast<std::uint64_t>(ux) >= range[0]) | (static_cast<std::uint64_t>(uy) >= range[1]) |
          (static_cast<std::uint64_t>(uz) >= range[2]))
        return;
      std::uint32_t n = 0;
      float value = 0.0f;
      if constexpr (C == Compounding::Mean) {
        n = rej <= 0 ? static_cast<std::uint32_t>(e - i) : cnt[e - ia] - cnt[i - ia];
        // exact below 2^24
        value = kBytes && rej <= 0 ? static_cast<float>(pre32[e - ia] - pre32[i - ia])
                                   : static_cast<float>(pre[e - ia] - pre[i - ia]);
      } else {
        int v = -1;
        for (int k = i; k < e; ++k) {
          const int p = row[k];
          if (p < rej) continue;
          v = C == Compounding::Latest ? p : std::max(v, p);
          ++n;
        }
        value = static_cast<float>(v);
      }
      if (n == 0) return;
      const std::int64_t x = bd.lo[0] + ux, y = bd.lo[1] + uy, z = bd.lo[2] + uz;
      const std::int64_t idx = x + y * sy + z * sz;
      FloatCell& c = cells[idx];
      if constexpr (C == Compounding::Mean) c.s += value;
      if constexpr (C == Compounding::Latest) c.s = value;
      if constexpr (C == Compounding::Maximum) c.s = std::max(c.s, value);
      c.w += static_cast<float>(n);
      wr.add(idx, x, y, z);
      inserted += n;
    });
  }
  out.pixels += inserted;
}

// PLUS's FULL-optimisation nearest neighbour (§3.3, §3.6): voxel floor(v + 1/2)
// of the fixed position, PLUS's compounding applied pixel by pixel (in
// registers along a segment).
template <Compounding C>
void nearestPlus(const Job& job, PlusCell* cells, const Slab& slab, bool split, SlabOut& out) {
  using namespace plusmath;
  const Bounds bd(job, slab);
  const std::int64_t sy = job.sy, sz = job.sz;
  const int rej = job.rejectBelow;
  std::uint64_t inserted = 0;
  for (const PixelRun& r : *job.runs) {
    const std::uint8_t* row = rowPtr<std::uint8_t>(job, r.y);
    FixedAxis ax[3];
    for (int a = 0; a < 3; ++a) ax[a] = FixedAxis(job.fmap.O[a] + std::int64_t{r.y} * job.fmap.Y[a] + kHalf, job.fmap.X[a]);
    int ia = r.x0, ib = r.x1;
    if (split) {
      const int a = slab.axis;
      columnRange(double(ax[a].b) / kOne, double(ax[a].X) / kOne, double(bd.lo[a]), double(bd.hi[a]), r.x0, r.x1, ia,
                  ib);
    }
    if (ia > ib) continue;
    RowWrites wr(job, out, static_cast<std::size_t>(ib - ia + 1));  // a voxel per segment at most
    walkRun(ax, ia, ib, [&](int i, int e, const std::int64_t* q) {
      const std::int64_t x = q[0], y = q[1], z = q[2];
      if (!(bd.owns(0, x) && bd.owns(1, y) && bd.owns(2, z))) return;
      const std::int64_t idx = x + y * sy + z * sz;
      std::uint32_t v = cells[idx].v, acc = cells[idx].a, n = 0;
      for (int k = i; k < e; ++k) {
        const std::uint32_t in = row[k];
        if (static_cast<int>(in) < rej) continue;
        ++n;
        if constexpr (C == Compounding::Mean) {
          if (acc <= 65279u) {
            // PLUS: v = (in*256 + v*acc) / (acc + 256), an integer division
            // that truncates at every step. acc is a multiple of 256 here (the
            // k - 1 earlier hits), so this is (in + v*(k-1)) / k.
            const std::uint32_t hits = (acc >> 8) + 1u;
            v = plusmath::divSmall(in + v * (hits - 1u), hits);
            acc += 256u;
          } else {
            // Saturated accumulator: PLUS's recursive filter, truncated.
            v = static_cast<std::uint32_t>(in * (1.0 / 256.0) + v * (255.0 / 256.0));
          }
        }
        if constexpr (C == Compounding::Latest) {
          v = in;
          acc = 256u;
        }
        if constexpr (C == Compounding::Maximum) {
          v = std::max(v, in);
          acc = 256u;
        }
      }
      if (n == 0) return;
      cells[idx].v = static_cast<std::uint8_t>(v);
      cells[idx].a = static_cast<std::uint16_t>(acc);
      wr.add(idx, x, y, z);
      inserted += n;
    });
  }
  out.pixels += inserted;
}

// ---------------------------------------------------------------------------
// Trilinear. Consecutive pixels with the same lower corner n0 form a group
// (float: a walker segment): their contributions to the eight corners are
// gathered in registers and each corner is written once per group (float), or
// the corners' PLUS state is carried in registers through the group (plus).
// As for nearest neighbour the groups do not depend on the slab cut.

using simd::F4;
using simd::I4;

// Float: corner k = 4*bx + 2*by + bz; lanes 0..3 of the "lo" vectors are
// bx = 0 (by, bz = 00, 01, 10, 11), of the "hi" vectors bx = 1.
template <class Pix, Compounding C>
void trilinearFloat(const Job& job, FloatCell* cells, const Slab& slab, bool split, SlabOut& out) {
  const Bounds bd(job, slab);
  const int sa = slab.axis;
  const std::int64_t sy = job.sy, sz = job.sz;
  const int rej = job.rejectBelow;
  const double X0 = job.map.X[0], X1 = job.map.X[1], X2 = job.map.X[2];
  const float x0f = static_cast<float>(X0), x1f = static_cast<float>(X1), x2f = static_cast<float>(X2);
  // A segment can reach the thread's voxels only if n0 is in [lo-1, hi-1] on every axis.
  std::int64_t off[3];
  std::uint64_t range[3];
  for (int a = 0; a < 3; ++a) {
    off[a] = kOffsetI + bd.lo[a] - 1;
    range[a] = static_cast<std::uint64_t>(bd.hi[a] - bd.lo[a] + 1);
  }
  std::uint64_t inserted = 0;
  const F4 eighth = {kMinWeightFloat, kMinWeightFloat, kMinWeightFloat, kMinWeightFloat};
  const F4 zero = {0, 0, 0, 0};

  for (const PixelRun& r : *job.runs) {
    const Pix* row = rowPtr<Pix>(job, r.y);
    FloatStep st[3];
    for (int a = 0; a < 3; ++a) st[a] = FloatStep(job.map.O[a] + double(r.y) * job.map.Y[a] + kOffset, job.map.X[a]);
    const double b0 = st[0].b, b1 = st[1].b, b2 = st[2].b;
    int ia = r.x0, ib = r.x1;
    if (split)
      columnRange(st[sa].b, st[sa].X, kOffset + double(bd.lo[sa]) - 1.0, kOffset + double(bd.hi[sa]), r.x0, r.x1, ia,
                  ib);
    if (ia > ib) continue;
    RowWrites wr(job, out, 8 * static_cast<std::size_t>(ib - ia + 1));  // eight corners per segment at most
    walkRunFloat(st, ia, ib, out.marks.data(), [&](int i, int e, std::int64_t mx, std::int64_t my, std::int64_t mz) {
      if ((static_cast<std::uint64_t>(mx - off[0]) >= range[0]) | (static_cast<std::uint64_t>(my - off[1]) >= range[1]) |
          (static_cast<std::uint64_t>(mz - off[2]) >= range[2]))
        return;
      // Corner k = 4*bx + 2*by + bz; lanes 0..3 of the "lo" vectors hold
      // bx = 0 (by bz = 00, 01, 10, 11), the "hi" vectors bx = 1. MEAN keeps
      // weighted sums, LATEST / MAXIMUM values.
      F4 slo = zero, shi = zero, wlo = zero, whi = zero;
      // The fractions at the segment's first pixel, from the row in double
      // (the segment decides n0; clamped against rounding), then stepped in
      // float from pixel to pixel: y and z as the vectors (1-fy, 1-fy, fy, fy)
      // and (1-fz, fz, 1-fz, fz), so that each pixel's eight weights take
      // three products. The steps' rounding (about 1e-7 over a segment) is
      // clamped away at zero.
      const double di = i;
      const float f0 = static_cast<float>(std::min(std::max(b0 + di * X0 - double(mx), 0.0), 1.0));
      const float f1 = static_cast<float>(std::min(std::max(b1 + di * X1 - double(my), 0.0), 1.0));
      const float f2 = static_cast<float>(std::min(std::max(b2 + di * X2 - double(mz), 0.0), 1.0));
      F4 Y = {1.0f - f1, 1.0f - f1, f1, f1}, Z = {1.0f - f2, f2, 1.0f - f2, f2};
      F4 XL = zero + (1.0f - f0), XH = zero + f0;
      const F4 dY = {-x1f, -x1f, x1f, x1f}, dZ = {-x2f, x2f, -x2f, x2f}, dX = zero + x0f;
      std::uint32_t n = 0;
      for (int k = i; k < e; ++k) {
        const int inI = row[k];
        const F4 yz = Y * Z;
        F4 lo = yz * XL, hi = yz * XH;
        Y += dY;
        Z += dZ;
        XL -= dX;
        XH += dX;
        if (inI < rej) continue;
        ++n;
        lo = lo > zero ? lo : zero;
        hi = hi > zero ? hi : zero;
        const float in = static_cast<float>(inI);
        if constexpr (C == Compounding::Mean) {
          slo += lo * in;
          shi += hi * in;
          wlo += lo;
          whi += hi;
        } else {
          // Only where the weight is at least 1/8 (PLUS's rule).
          const I4 mlo = lo >= eighth, mhi = hi >= eighth;
          const F4 vin = {in, in, in, in};
          if constexpr (C == Compounding::Latest) {
            slo = mlo ? vin : slo;
            shi = mhi ? vin : shi;
          } else {
            slo = mlo ? (slo > vin ? slo : vin) : slo;
            shi = mhi ? (shi > vin ? shi : vin) : shi;
          }
          wlo += mlo ? lo : zero;
          whi += mhi ? hi : zero;
        }
      }
      if (n == 0) return;
      const std::int64_t c0 = mx - kOffsetI, c1 = my - kOffsetI, c2 = mz - kOffsetI;
      if (c0 >= bd.lo[0] && c0 + 1 < bd.hi[0] && c1 >= bd.lo[1] && c1 + 1 < bd.hi[1] && c2 >= bd.lo[2] &&
          c2 + 1 < bd.hi[2]) {
        // All eight corners are the thread's (the common case).
        const std::int64_t idx = c0 + c1 * sy + c2 * sz;
        const std::int64_t offs[8] = {0, sz, sy, sy + sz, 1, 1 + sz, 1 + sy, 1 + sy + sz};
        const std::int64_t bxs[2] = {wr.bx(c0), wr.bx(c0 + 1)}, bys[2] = {wr.by(c1), wr.by(c1 + 1)},
                           bzs[2] = {wr.bz(c2), wr.bz(c2 + 1)};
        for (int k = 0; k < 8; ++k) {
          const int lane = k & 3;
          const float w = k & 4 ? whi[lane] : wlo[lane];
          const float v = k & 4 ? shi[lane] : slo[lane];
          FloatCell& cell = cells[idx + offs[k]];
          if constexpr (C == Compounding::Mean) {
            cell.s += v;  // adding a zero weight changes nothing
            cell.w += w;
          } else if (w > 0.0f) {
            cell.s = C == Compounding::Latest ? v : std::max(cell.s, v);
            cell.w += w;
          }
          wr.add(idx + offs[k], bxs[k >> 2] + bys[(k >> 1) & 1] + bzs[k & 1]);
        }
        if (bd.owns(sa, sa == 0 ? c0 : sa == 1 ? c1 : c2)) inserted += n;
        return;
      }
      for (int k = 0; k < 8; ++k) {
        const int bx = k >> 2, by = (k >> 1) & 1, bz = k & 1;
        const std::int64_t x = c0 + bx, y = c1 + by, z = c2 + bz;
        if (!bd.owns(0, x) || !bd.owns(1, y) || !bd.owns(2, z)) continue;
        const int lane = k & 3;
        const float w = bx ? whi[lane] : wlo[lane];
        if (!(w > 0.0f)) continue;
        const float s = bx ? shi[lane] : slo[lane];
        const std::int64_t idx = x + y * sy + z * sz;
        FloatCell& cell = cells[idx];
        if constexpr (C == Compounding::Mean) cell.s += s;
        if constexpr (C == Compounding::Latest) cell.s = s;
        if constexpr (C == Compounding::Maximum) cell.s = std::max(cell.s, s);
        cell.w += w;
        wr.add(idx, x, y, z);
      }
      // Pixels that reach the grid, counted by the owner of their lowest layer inside it.
      const std::int64_t cs = sa == 0 ? c0 : sa == 1 ? c1 : c2;
      if (bd.owns(sa, std::max<std::int64_t>(cs, 0))) inserted += n;
    });
  }
  out.pixels += inserted;
}

// PLUS's FULL-optimisation trilinear splat (§4): fixed-point weights, the
// pixel dropped unless all eight corners are inside the grid, corners of
// weight 0 skipped. PLUS visits corners k = 7..0, but corners of non-zero
// weight are distinct voxels, so their order changes nothing.
template <Compounding C>
void trilinearPlus(const Job& job, PlusCell* cells, const Slab& slab, bool split, SlabOut& out) {
  using namespace plusmath;
  const Bounds bd(job, slab);
  const int sa = slab.axis;
  const std::int64_t sy = job.sy, sz = job.sz;
  const std::int64_t X0 = job.fmap.X[0], X1 = job.fmap.X[1], X2 = job.fmap.X[2];
  const std::uint64_t E[3] = {static_cast<std::uint64_t>(job.dims.x), static_cast<std::uint64_t>(job.dims.y),
                              static_cast<std::uint64_t>(job.dims.z)};
  std::uint64_t inserted = 0;
  for (const PixelRun& r : *job.runs) {
    const std::uint8_t* row = rowPtr<std::uint8_t>(job, r.y);
    std::int64_t b[3];
    for (int a = 0; a < 3; ++a) b[a] = job.fmap.O[a] + std::int64_t{r.y} * job.fmap.Y[a];
    int ia = r.x0, ib = r.x1;
    if (split)
      columnRange(double(b[sa]) / kOne, double(job.fmap.X[sa]) / kOne, double(bd.lo[sa]) - 1.0, double(bd.hi[sa]),
                  r.x0, r.x1, ia, ib);
    if (ia > ib) continue;
    RowWrites wr(job, out, 8 * static_cast<std::size_t>(ib - ia + 1));  // a group per pixel at most

    // The group: lower corner c, and per corner the PLUS state in registers.
    std::int64_t cur = -1;
    std::int64_t c[3] = {0, 0, 0};
    std::int32_t v[8], acc[8];
    std::uint32_t valid = 0, modified = 0;
    auto flush = [&] {
      for (int k = 0; k < 8; ++k) {
        if (!((valid & modified) >> k & 1u)) continue;
        const std::int64_t x = c[0] + (k >> 2), y = c[1] + ((k >> 1) & 1), z = c[2] + (k & 1);
        const std::int64_t idx = x + y * sy + z * sz;
        cells[idx].v = static_cast<std::uint8_t>(v[k]);
        cells[idx].a = static_cast<std::uint16_t>(acc[k]);
        wr.add(idx, x, y, z);
      }
    };
    for (int i = ia; i <= ib; ++i) {
      const std::int32_t in = row[i];
      if (in < job.rejectBelow) continue;
      const std::int64_t P[3] = {b[0] + i * X0, b[1] + i * X1, b[2] + i * X2};
      std::int64_t n0[3];
      std::int32_t f[3];
      bool inside = true;
      for (int a = 0; a < 3; ++a) {
        n0[a] = P[a] >> kFracBits;
        f[a] = static_cast<std::int32_t>(P[a] - (n0[a] << kFracBits));
        const std::int64_t n1 = n0[a] + (f[a] != 0);
        // All or nothing against the whole grid (unsigned: a negative n0 fails too).
        inside &= (static_cast<std::uint64_t>(n0[a]) < E[a]) & (static_cast<std::uint64_t>(n1) < E[a]);
      }
      if (!inside) continue;
      if (!bd.owns(sa, n0[sa]) && !bd.owns(sa, n0[sa] + 1)) continue;
      const std::int64_t key = n0[0] + n0[1] * sy + n0[2] * sz;
      if (key != cur) {
        if (cur >= 0) flush();
        cur = key;
        c[0] = n0[0];
        c[1] = n0[1];
        c[2] = n0[2];
        valid = modified = 0;
        for (int k = 0; k < 8; ++k) {
          const std::int64_t x = c[0] + (k >> 2), y = c[1] + ((k >> 1) & 1), z = c[2] + (k & 1);
          // A corner outside the grid only ever gets weight 0 (its axis has f = 0).
          if (bd.owns(0, x) && bd.owns(1, y) && bd.owns(2, z)) {
            const PlusCell& cell = cells[x + y * sy + z * sz];
            v[k] = cell.v;
            acc[k] = cell.a;
            valid |= 1u << k;
          } else {
            v[k] = acc[k] = 0;
          }
        }
      }
      if (bd.owns(sa, n0[sa])) ++inserted;
      const std::int32_t rx = kOne - f[0], ry = kOne - f[1], rz = kOne - f[2];
      const std::int32_t ryrz = mul(ry, rz), ryfz = mul(ry, f[2]), fyrz = mul(f[1], rz), fyfz = mul(f[1], f[2]);
      const std::int32_t w[8] = {mul(rx, ryrz),   mul(rx, ryfz),   mul(rx, fyrz),   mul(rx, fyfz),
                                 mul(f[0], ryrz), mul(f[0], ryfz), mul(f[0], fyrz), mul(f[0], fyfz)};
#pragma GCC unroll 8
      for (int k = 7; k >= 0; --k) {
        const std::int32_t wk = w[k];
        if (wk == 0) continue;
        // PLUS sets the accumulator to round((w + acc/256) * 256), capped at
        // 65535 (LATEST / MAXIMUM: round(w * 256)); acc/256 is exact in
        // fixed point, so that is acc + round(w / 64).
        const std::int32_t dacc = (wk + 32) >> 6;
        if constexpr (C == Compounding::Mean) {
          const std::int32_t rr = acc[k] * 64;  // acc / 256 as fixed, exact
          // The fixed division: the quotient rounded to double, then to 2^-14.
          v[k] = roundToInt(div(wk * in + rr * v[k], wk + rr));
          acc[k] = std::min(acc[k] + dacc, 65535);
        } else {
          const bool set = C == Compounding::Latest ? wk >= kMinWeightFixed : (wk >= kMinWeightFixed && in > v[k]);
          if (!set) continue;
          v[k] = in;
          acc[k] = dacc;  // replaced, not added to
        }
        modified |= 1u << k;
      }
    }
    if (cur >= 0) flush();
  }
  out.pixels += inserted;
}

}  // namespace

void splatPlus(Method method, Compounding comp, const Job& job, PlusCell* c, const Slab& slab, bool split,
               SlabOut& so) {
  if (method == Method::Nearest) {
    switch (comp) {
      case Compounding::Mean: nearestPlus<Compounding::Mean>(job, c, slab, split, so); break;
      case Compounding::Latest: nearestPlus<Compounding::Latest>(job, c, slab, split, so); break;
      case Compounding::Maximum: nearestPlus<Compounding::Maximum>(job, c, slab, split, so); break;
    }
  } else {
    switch (comp) {
      case Compounding::Mean: trilinearPlus<Compounding::Mean>(job, c, slab, split, so); break;
      case Compounding::Latest: trilinearPlus<Compounding::Latest>(job, c, slab, split, so); break;
      case Compounding::Maximum: trilinearPlus<Compounding::Maximum>(job, c, slab, split, so); break;
    }
  }
}

void splatFloat(Method method, Compounding comp, const Job& job, FloatCell* c, const Slab& slab, bool split,
                SlabOut& so) {
  auto run = [&]<class Pix>() {
    if (method == Method::Nearest) {
      switch (comp) {
        case Compounding::Mean: nearestFloat<Pix, Compounding::Mean>(job, c, slab, split, so); break;
        case Compounding::Latest: nearestFloat<Pix, Compounding::Latest>(job, c, slab, split, so); break;
        case Compounding::Maximum: nearestFloat<Pix, Compounding::Maximum>(job, c, slab, split, so); break;
      }
    } else {
      switch (comp) {
        case Compounding::Mean: trilinearFloat<Pix, Compounding::Mean>(job, c, slab, split, so); break;
        case Compounding::Latest: trilinearFloat<Pix, Compounding::Latest>(job, c, slab, split, so); break;
        case Compounding::Maximum: trilinearFloat<Pix, Compounding::Maximum>(job, c, slab, split, so); break;
      }
    }
  };
  if (job.u16)
    run.template operator()<std::uint16_t>();
  else
    run.template operator()<std::uint8_t>();
}

}  // namespace pp5::gp::pixel
