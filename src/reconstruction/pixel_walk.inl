// A part of reconstruction/pixel_kernels.cpp, included there inside its unnamed
// namespace: the pixel kernels are one translation unit, so that they compile
// exactly as they did in one file (the compiler inlines a helper by how many
// calls it sees), cut into the walk they share and one file per method to
// keep each file short. Not a header: it includes nothing and stands alone.
// The shared walk: a row's voxel runs, the slab bounds, the prefix sums.

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

