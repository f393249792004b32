#include "rendering/change_tracker.hpp"

#include <algorithm>
#include <bit>
#include <climits>
#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>

#include "core/error.hpp"
#include "rendering/change_tracker_detail.hpp"
#include "reconstruction/voxel_array.hpp"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace pp5::gp {

namespace {

// One row's ranges (lo > hi: none), x relative to the row's first voxel.
struct RowScan {
  std::int32_t changedLo = kNone, changedHi = -1;  // values that changed
  std::int32_t selfLo = kNone, selfHi = -1;        // ... and were or are visible
};


// Compares n values of a row with the copy (by their bits), takes the new
// ones into the copy, and notes the ranges.
template <class T>
RowScan scanRow(const std::uint8_t* nowBytes, std::uint8_t* wasBytes, std::int32_t n, const TransferFunction* tf) {
  using Bits = std::conditional_t<sizeof(T) == 1, std::uint8_t,
                                  std::conditional_t<sizeof(T) == 2, std::uint16_t, std::uint32_t>>;
  RowScan s;
  auto visible = [&](Bits b) { return !tf || !tf->transparentUpTo(static_cast<float>(std::bit_cast<T>(b))); };
  for (std::int32_t v = 0; v < n; ++v) {
    Bits now, was;
    std::memcpy(&now, nowBytes + v * static_cast<std::int64_t>(sizeof(T)), sizeof(T));
    std::memcpy(&was, wasBytes + v * static_cast<std::int64_t>(sizeof(T)), sizeof(T));
    if (now == was) continue;
    s.changedLo = std::min(s.changedLo, v);
    s.changedHi = v;
    if (visible(now) || visible(was)) {
      s.selfLo = std::min(s.selfLo, v);
      s.selfHi = v;
    }
  }
  if (s.changedLo <= s.changedHi) {
    const auto B = static_cast<std::int64_t>(sizeof(T));
    std::memcpy(wasBytes + s.changedLo * B, nowBytes + s.changedLo * B,
                static_cast<std::size_t>((s.changedHi - s.changedLo + 1) * B));
  }
  return s;
}

#if defined(__SSE2__)
// Four floats at a time, the lanes that transparentUpTo calls visible (tf
// null: all), by the same float operations: x = v <= 0 ? 0 : v >= 255 ? 255
// : v, visible unless x * steps < below (a NaN stays visible, as there).
class VisibleLanes {
public:
  explicit VisibleLanes(const TransferFunction* tf)
      : tf_(tf != nullptr), below_(_mm_set1_ps(tf ? tf->transparentBelow() : 0.0f)) {}
  int operator()(__m128 v) const {
    if (!tf_) return 0xf;
    const __m128 zero = _mm_setzero_ps(), top = _mm_set1_ps(255.0f);
    const __m128 steps = _mm_set1_ps(static_cast<float>(TransferFunction::kStepsPerLevel));
    const __m128 le = _mm_cmple_ps(v, zero), ge = _mm_cmpge_ps(v, top);
    const __m128 clamped = _mm_or_ps(_mm_and_ps(ge, top), _mm_andnot_ps(ge, v));
    const __m128 x = _mm_andnot_ps(le, clamped);
    return _mm_movemask_ps(_mm_cmplt_ps(_mm_mul_ps(x, steps), below_)) ^ 0xf;
  }

private:
  bool tf_;
  __m128 below_;
};

// Widens [lo, hi] by the set lanes of `mask`, lane 0 at x = at.
inline void noteLanes(std::int32_t& lo, std::int32_t& hi, int mask, std::int32_t at) {
  if (!mask) return;
  lo = std::min(lo, at + std::countr_zero(static_cast<unsigned>(mask)));
  hi = std::max(hi, at + 31 - std::countl_zero(static_cast<unsigned>(mask)));
}

// scanRow for float values, four at a time without a branch per voxel (the
// speckle of a reconstruction makes "visible" a coin toss, which a branch
// mispredicts): the same tests by the same float operations, so the same
// ranges.
RowScan scanRowF32(const std::uint8_t* nowBytes, std::uint8_t* wasBytes, std::int32_t n, const TransferFunction* tf) {
  RowScan s;
  const VisibleLanes visible(tf);
  const auto note = noteLanes;
  std::int32_t v = 0;
  for (; v + 4 <= n; v += 4) {
    const __m128i nowI = _mm_loadu_si128(reinterpret_cast<const __m128i*>(nowBytes + 4 * v));
    const __m128i wasI = _mm_loadu_si128(reinterpret_cast<const __m128i*>(wasBytes + 4 * v));
    const int changed = _mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(nowI, wasI))) ^ 0xf;
    if (!changed) continue;
    note(s.changedLo, s.changedHi, changed, v);
    note(s.selfLo, s.selfHi, changed & (visible(_mm_castsi128_ps(nowI)) | visible(_mm_castsi128_ps(wasI))), v);
  }
  if (v < n) {
    // The last one to three, by the scalar scan.
    const RowScan t = scanRow<float>(nowBytes + 4 * v, wasBytes + 4 * v, n - v, tf);
    auto widen = [&](std::int32_t& lo, std::int32_t& hi, std::int32_t a, std::int32_t z) {
      if (a > z) return;
      lo = std::min(lo, v + a);
      hi = v + z;
    };
    widen(s.changedLo, s.changedHi, t.changedLo, t.changedHi);
    widen(s.selfLo, s.selfHi, t.selfLo, t.selfHi);
  }
  // The copy takes the changed range (the tail's part again, the same bytes).
  if (s.changedLo <= s.changedHi)
    std::memcpy(wasBytes + 4 * s.changedLo, nowBytes + 4 * s.changedLo,
                static_cast<std::size_t>(s.changedHi - s.changedLo + 1) * 4);
  return s;
}
#endif

// The first (last) set bit of `bits` in [from, to], or -1.
std::int64_t firstSetBit(const std::vector<std::uint64_t>& bits, std::int64_t from, std::int64_t to) {
  for (std::int64_t w = from / 64; w <= to / 64; ++w) {
    std::uint64_t word = bits[static_cast<std::size_t>(w)];
    if (w == from / 64) word &= ~std::uint64_t{0} << (from % 64);
    if (w == to / 64 && to % 64 != 63) word &= (std::uint64_t{1} << (to % 64 + 1)) - 1;
    if (word) return w * 64 + std::countr_zero(word);
  }
  return -1;
}
std::int64_t lastSetBit(const std::vector<std::uint64_t>& bits, std::int64_t from, std::int64_t to) {
  for (std::int64_t w = to / 64; w >= from / 64; --w) {
    std::uint64_t word = bits[static_cast<std::size_t>(w)];
    if (w == from / 64) word &= ~std::uint64_t{0} << (from % 64);
    if (w == to / 64 && to % 64 != 63) word &= (std::uint64_t{1} << (to % 64 + 1)) - 1;
    if (word) return w * 64 + 63 - std::countl_zero(word);
  }
  return -1;
}

// The least value that `tf` does not make transparent (transparentUpTo is
// false from it on, true below it; +infinity when every value is
// transparent, -infinity when none is or there is no `tf`), found over the
// bits of the floats in [0, 255], which order as integers there. A value
// (never NaN) compared with it gets transparentUpTo's answer, but for
// +infinity under a function that makes everything transparent, which it
// takes for visible (a row kept that could be left out).
float visibleFrom(const TransferFunction* f) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  if (!f) return -kInf;
  const TransferFunction& tf = *f;
  if (tf.transparentUpTo(kInf)) return kInf;
  if (!tf.transparentUpTo(0.0f)) return -kInf;
  std::uint32_t lo = std::bit_cast<std::uint32_t>(0.0f), hi = std::bit_cast<std::uint32_t>(255.0f);  // lo transparent, hi not
  while (hi - lo > 1) {
    const std::uint32_t mid = lo + (hi - lo) / 2;
    if (tf.transparentUpTo(std::bit_cast<float>(mid))) lo = mid;
    else hi = mid;
  }
  return std::bit_cast<float>(hi);
}

// Narrows [a, z] of the row at `row` (its first voxel's bytes) to its first
// and last voxel for which keep(value, x) holds (a > z: none).
template <class T, class Keep>
void narrowRow(const std::uint8_t* row, std::int64_t& a, std::int64_t& z, Keep&& keep) {
  while (a <= z && !keep(loadValue<T>(row, a), a)) ++a;
  while (z > a && !keep(loadValue<T>(row, z), z)) --z;
}

// Narrows [a, z] of a row of values to its first and last visible voxel.
void narrowToVisible(ScalarType type, const std::uint8_t* row, std::int64_t& a, std::int64_t& z,
                     const TransferFunction& tf) {
  auto keep = [&](float v, std::int64_t) { return !tf.transparentUpTo(v); };
  switch (type) {
    case ScalarType::U8: narrowRow<std::uint8_t>(row, a, z, keep); break;
    case ScalarType::U16: narrowRow<std::uint16_t>(row, a, z, keep); break;
    case ScalarType::F32: {
#if defined(__SSE2__)
      // Four at a time and no branch on the (speckled) visibility: the
      // visible lanes' range, over the groups of four inside [a, z] and the
      // last one to three one by one.
      const VisibleLanes visible(&tf);
      std::int32_t lo = kNone, hi = -1;
      const auto* f = reinterpret_cast<const float*>(row);
      auto x = static_cast<std::int32_t>(a);
      for (; x + 3 <= z; x += 4) noteLanes(lo, hi, visible(_mm_loadu_ps(f + x)), x);
      for (; x <= z; ++x)
        if (keep(loadValue<float>(row, x), x)) noteLanes(lo, hi, 1, x);
      a = lo;
      z = hi;
#else
      narrowRow<float>(row, a, z, keep);
#endif
      break;
    }
  }
}

}  // namespace

void ChangeTracker::noteRow(std::int64_t row, std::int32_t lo, std::int32_t hi, std::int32_t sLo, std::int32_t sHi) {
  if (lo > hi) return;
  RowRanges& e = ranges_[static_cast<std::size_t>(row)];
  if (e.lo > e.hi) rowsTouched_.push_back(row);
  e.lo = std::min(e.lo, lo);
  e.hi = std::max(e.hi, hi);
  if (sLo <= sHi) {
    e.selfLo = std::min(e.selfLo, sLo);
    e.selfHi = std::max(e.selfHi, sHi);
  }
}

std::vector<Box3> ChangeTracker::shadingRuns(const Volume& values, std::span<const Box3> dirty,
                                             std::span<const Box3> within, const TransferFunction* tf) {
  PP5_CHECK(compares());
  PP5_CHECK(values.grid.dims == grid_.dims);
  PP5_CHECK(values.type == type_);
  const Index3 d = grid_.dims;
  const ScalarType type = values.type;
  const std::int64_t B = scalarBytes(type);
  const Box3 all{Index3(0), d};
  // One pass over the values of `dirty`: what changed.
  for (const Box3& b0 : dirty) {
    const Box3 b = b0.intersect(all);
    if (b.empty()) continue;
    const std::int64_t len = (b.hi.x - b.lo.x) * B;
    const auto n = static_cast<std::int32_t>(b.hi.x - b.lo.x);
    const auto x0 = static_cast<std::int32_t>(b.lo.x);
    for (std::int64_t k = b.lo.z; k < b.hi.z; ++k)
      for (std::int64_t j = b.lo.y; j < b.hi.y; ++j) {
        const std::int64_t row = k * d.y + j;
        const std::int64_t off = (row * d.x + b.lo.x) * B;
        // Rows of a box thin in x are short and a kilobyte or more apart,
        // which the hardware does not fetch ahead: fetch the row kAhead on.
        if (j + kAhead < b.hi.y) {
          const std::int64_t ahead = off + kAhead * d.x * B;
          for (std::int64_t o = 0; o < len + 63; o += 64) {
            __builtin_prefetch(values.bytes.data() + ahead + std::min(o, len - 1), 0, 3);
            __builtin_prefetch(copy_.bytes.data() + ahead + std::min(o, len - 1), 1, 3);
          }
        }
        RowScan r;
        switch (type) {
          case ScalarType::U8: r = scanRow<std::uint8_t>(values.bytes.data() + off, copy_.bytes.data() + off, n, tf); break;
          case ScalarType::U16: r = scanRow<std::uint16_t>(values.bytes.data() + off, copy_.bytes.data() + off, n, tf); break;
          case ScalarType::F32:
#if defined(__SSE2__)
            r = scanRowF32(values.bytes.data() + off, copy_.bytes.data() + off, n, tf);
#else
            r = scanRow<float>(values.bytes.data() + off, copy_.bytes.data() + off, n, tf);
#endif
            break;
        }
        if (r.changedLo > r.changedHi) continue;
        noteRow(row, x0 + r.changedLo, x0 + r.changedHi, r.selfLo > r.selfHi ? kNone : x0 + r.selfLo,
                r.selfLo > r.selfHi ? -1 : x0 + r.selfHi);
      }
  }
  return runsWithin(values, within, tf);
}

std::vector<Box3> ChangeTracker::shadingRuns(const Volume& values, std::span<const RowRun> changed,
                                             std::span<const Box3> within, const TransferFunction* tf) {
  noteReported(values, changed, tf);
  return runsWithin(values, within, tf);
}

std::vector<Box3> ChangeTracker::shadingRuns(const Volume& values, std::span<const RowRun> changed,
                                             const Box3& region, const TransferFunction* tf) {
  noteReported(values, changed, tf);
  return runsWithin(values, {}, tf, &region);
}

void ChangeTracker::noteReported(const Volume& values, std::span<const RowRun> changed, const TransferFunction* tf) {
  PP5_CHECK(!compares());
  PP5_CHECK(values.grid.dims == grid_.dims);
  PP5_CHECK(values.type == type_);
  const Index3 d = grid_.dims;
  // A run clipped to the grid, or none (a > z).
  auto clip = [&](const RowRun& c, std::int64_t& row, std::int64_t& a, std::int64_t& z) {
    a = 1;
    z = 0;
    if (c.j < 0 || c.j >= d.y || c.k < 0 || c.k >= d.z) return;
    a = std::max<std::int64_t>(c.i0, 0);
    z = std::min<std::int64_t>(c.i1, d.x - 1);
    row = std::int64_t{c.k} * d.y + c.j;
  };
  // First every row's bound, so that the second pass sees each row's bound
  // after this call.
  for (const RowRun& c : changed) {
    std::int64_t row = 0, a, z;
    clip(c, row, a, z);
    if (a > z) continue;
    float& bound = rowMax_[static_cast<std::size_t>(row)];
    if (!(c.newMax <= bound)) bound = std::isnan(c.newMax) ? std::numeric_limits<float>::infinity() : c.newMax;
  }
  const float from = visibleFrom(tf);
  auto transparent = [&](std::int64_t r) { return transparentRow(r, from); };
  for (const RowRun& c : changed) {
    std::int64_t row = 0, a, z;
    clip(c, row, a, z);
    if (a > z) continue;
    // A row of water (its bound transparent) whose four face neighbours
    // are water too matters to no voxel: it has no visible voxel to shade,
    // and had none (its bound was lower), and no neighbour reads its
    // changes for a visible voxel's gradient. Most of a frame's rows are.
    const bool water = transparent(row);
    if (water && (c.j == 0 || transparent(row - 1)) && (c.j + 1 == d.y || transparent(row + 1)) &&
        (c.k == 0 || transparent(row - d.y)) && (c.k + 1 == d.z || transparent(row + d.y)))
      continue;
    const auto lo = static_cast<std::int32_t>(a), hi = static_cast<std::int32_t>(z);
    // Of the changed voxels, those shaded before: the ones visible now are
    // in this row's range of changes, which runsWithin narrows to them. A
    // voxel shaded before had a visible value then, which the row's bound
    // was at least: a row of water had none, and its bits need not be read.
    std::int32_t sLo = lo, sHi = hi;
    if (water) {
      sLo = kNone;
      sHi = -1;
    } else if (tf) {
      const std::int64_t base = row * d.x;
      const std::int64_t first = firstSetBit(shadedBits_, base + a, base + z);
      sLo = kNone;
      sHi = -1;
      if (first >= 0) {
        sLo = static_cast<std::int32_t>(first - base);
        sHi = static_cast<std::int32_t>(lastSetBit(shadedBits_, base + a, base + z) - base);
      }
    }
    noteRow(row, lo, hi, sLo, sHi);
  }
}

std::vector<Box3> ChangeTracker::runsWithin(const Volume& values, std::span<const Box3> within,
                                            const TransferFunction* tf, const Box3* region) {
  const Index3 d = grid_.dims;
  const std::int64_t B = scalarBytes(values.type);
  const Box3 all{Index3(0), d};
  const float from = visibleFrom(tf);
  std::vector<Box3> out;
  // Row (j, k) with x clipped to [x0, x1]: its run, if any.
  auto visit = [&](std::int64_t j, std::int64_t k, std::int64_t x0, std::int64_t x1) {
    // The row and its four face-neighbour rows: a voxel reads x - 1 and
    // x + 1 of its own row and x of the others.
    std::int32_t lo = kNone, hi = -1;
    auto take = [&](std::int64_t jj, std::int64_t kk) {
      if (jj < 0 || jj >= d.y || kk < 0 || kk >= d.z) return;
      const RowRanges& e = ranges_[static_cast<std::size_t>(kk * d.y + jj)];
      lo = std::min(lo, e.lo);
      hi = std::max(hi, e.hi);
    };
    take(j, k);
    take(j - 1, k);
    take(j + 1, k);
    take(j, k - 1);
    take(j, k + 1);
    if (lo > hi) return;
    // Of the voxels next to a change, the visible ones (the first to the
    // last, so a few more); and this row's own changes that were or are
    // visible.
    const auto r = static_cast<std::size_t>(k * d.y + j);
    std::int64_t a = std::max<std::int64_t>(lo - 1, x0), z = std::min<std::int64_t>(hi + 1, x1);
    if (transparentRow(static_cast<std::int64_t>(r), from)) {
      a = 1;  // no visible voxel in the row
      z = 0;
    } else if (tf) {
      narrowToVisible(values.type, values.bytes.data() + static_cast<std::int64_t>(r) * d.x * B, a, z, *tf);
    }
    const std::int64_t sa = std::max<std::int64_t>(ranges_[r].selfLo, x0);
    const std::int64_t sz = std::min<std::int64_t>(ranges_[r].selfHi, x1);
    if (a > z) {
      a = sa;
      z = sz;
    } else if (sa <= sz) {
      a = std::min(a, sa);
      z = std::max(z, sz);
    }
    if (a <= z) out.push_back({Index3(a, j, k), Index3(z + 1, j + 1, k + 1)});
  };
  if (!rowsTouched_.empty() && region) {
    // Only the rows that can have a run, marked and then read back in
    // ascending order (memory order): a changed row with changes of its own
    // that were or are visible, and the rows next to a changed row that are
    // not all transparent (most of a frame's changed rows are water, and so
    // are their neighbours). A changed row's index +-1 and +-dims.y are its
    // face neighbours, or, at the grid's y faces, other rows, visited for
    // nothing (visit() looks at the true neighbours); no division is needed.
    const Box3 w = region->intersect(all);
    const std::int64_t rows = d.y * d.z;
    if (rowMarks_.size() != static_cast<std::size_t>(rows)) rowMarks_.assign(static_cast<std::size_t>(rows), 0);
    std::int64_t first = rows, last = -1;
    auto mark = [&](std::int64_t r) {
      rowMarks_[static_cast<std::size_t>(r)] = 1;
      first = std::min(first, r);
      last = std::max(last, r);
    };
    for (const std::int64_t row : rowsTouched_) {
      const RowRanges& e = ranges_[static_cast<std::size_t>(row)];
      if (e.selfLo <= e.selfHi) mark(row);
      for (const std::int64_t r : {row, row - 1, row + 1, row - d.y, row + d.y})
        if (r >= 0 && r < rows && !transparentRow(r, from)) mark(r);
    }
    if (last >= 0) {
      std::int64_t j = first % d.y, k = first / d.y;
      for (std::int64_t r = first; r <= last; ++r) {
        if (rowMarks_[static_cast<std::size_t>(r)]) {
          rowMarks_[static_cast<std::size_t>(r)] = 0;
          if (!w.empty() && j >= w.lo.y && j < w.hi.y && k >= w.lo.z && k < w.hi.z) visit(j, k, w.lo.x, w.hi.x - 1);
        }
        if (++j == d.y) {
          j = 0;
          ++k;
        }
      }
    }
  } else if (!rowsTouched_.empty()) {
    for (const Box3& w0 : within) {
      const Box3 w = w0.intersect(all);
      if (w.empty()) continue;
      const std::int64_t len = (w.hi.x - w.lo.x) * B;
      for (std::int64_t k = w.lo.z; k < w.hi.z; ++k)
        for (std::int64_t j = w.lo.y; j < w.hi.y; ++j) {
          // The values a few rows on, which the narrowing may read (as in the
          // comparing pass, the hardware does not fetch them ahead).
          if (tf && j + kAhead < w.hi.y && !transparentRow(k * d.y + j + kAhead, from)) {
            const std::uint8_t* ahead = values.bytes.data() + ((k * d.y + j + kAhead) * d.x + w.lo.x) * B;
            for (std::int64_t o = 0; o < len + 63; o += 64) __builtin_prefetch(ahead + std::min(o, len - 1), 0, 3);
          }
          visit(j, k, w.lo.x, w.hi.x - 1);
        }
    }
  }
  for (const std::int64_t row : rowsTouched_) ranges_[static_cast<std::size_t>(row)] = RowRanges{kNone, -1, kNone, -1};
  rowsTouched_.clear();
  return out;
}

namespace {
// A voxel's (i, j, k) from its linear index, for voxels that come mostly in
// rows (as shade() reports them): the divisions only when the row changes.
class RowCursor {
public:
  explicit RowCursor(const Index3& d) : d_(d) {}
  void at(std::int64_t v, std::int64_t& i, std::int64_t& j, std::int64_t& k) {
    if (v < rowBase_ || v >= rowBase_ + d_.x) {
      const std::int64_t q = v / d_.x;
      rowBase_ = q * d_.x;
      j_ = q % d_.y;
      k_ = q / d_.y;
    }
    i = v - rowBase_;
    j = j_;
    k = k_;
  }

private:
  Index3 d_;
  std::int64_t rowBase_ = -(std::int64_t{1} << 62), j_ = 0, k_ = 0;  // no row yet: every voxel is outside it
};
}  // namespace

template <class F>
void ChangeTracker::forEachRun(F&& f) const {
  // shade() reports voxels mostly in ascending runs along x: each run once.
  const Index3 d = grid_.dims;
  RowCursor cur(d);
  std::size_t at = 0;
  while (at < changed_.size()) {
    std::int64_t i = 0, j = 0, k = 0;
    cur.at(changed_[at], i, j, k);
    std::size_t end = at + 1;
    std::int64_t i1 = i;
    while (end < changed_.size() && changed_[end] == changed_[end - 1] + 1 && i1 + 1 < d.x) {
      ++end;
      ++i1;
    }
    f(i, i1, j, k);
    at = end;
  }
}

void ChangeTracker::markCells(std::uint8_t value) {
  const Index3 d = grid_.dims;
  // Voxel (i, j, k) is a corner of cells i - 1 and i on each axis (those in
  // 0 .. dims - 2): a run i0 .. i1 of a row marks cells i0 - 1 .. i1 of four rows.
  forEachRun([&](std::int64_t i0, std::int64_t i1, std::int64_t j, std::int64_t k) {
    const std::int64_t c0 = std::max<std::int64_t>(i0 - 1, 0), c1 = std::min(i1, d.x - 2);
    if (c0 > c1) return;
    for (std::int64_t ck = std::max<std::int64_t>(k - 1, 0); ck <= std::min(k, d.z - 2); ++ck)
      for (std::int64_t cj = std::max<std::int64_t>(j - 1, 0); cj <= std::min(j, d.y - 2); ++cj)
        std::memset(cells_.data() + (ck * d.y + cj) * d.x + c0, value, static_cast<std::size_t>(c1 - c0 + 1));
  });
}

void ChangeTracker::setShadeChanges(std::span<const std::int64_t> voxels, const ShadeBuffer& shades) {
  for (const std::int64_t v : voxels) PP5_CHECK(v >= 0 && static_cast<std::uint64_t>(v) < grid_.voxelCount());
  PP5_CHECK(shades.grid().dims == grid_.dims);
  if (!compare_)
    for (const std::int64_t v : voxels) {
      const std::uint64_t bit = std::uint64_t{1} << (v % 64);
      std::uint64_t& w = shadedBits_[static_cast<std::size_t>(v / 64)];
      w = shades.at(static_cast<std::size_t>(v)) != ShadeVoxel{} ? (w | bit) : (w & ~bit);
    }
  if (++mark_ == 0) {
    // The marks wrapped: clear them all once, every 255 updates.
    std::fill(cells_.begin(), cells_.end(), std::uint8_t{0});
    mark_ = 1;
  }
  changed_.assign(voxels.begin(), voxels.end());
  markCells(mark_);
  bricks_.clear();
  runs_.clear();
  std::int64_t lastBrick = -1;
  forEachRun([&](std::int64_t i0, std::int64_t i1, std::int64_t j, std::int64_t k) {
    runs_.push_back({Index3(i0, j, k), Index3(i1 + 1, j + 1, k + 1)});
    const std::int64_t bj = j / kBrick, bk = k / kBrick;
    for (std::int64_t bi = i0 / kBrick; bi <= i1 / kBrick; ++bi) {
      const std::int64_t id = (bk * bricks_.brickDims().y + bj) * bricks_.brickDims().x + bi;
      if (id == lastBrick) continue;
      lastBrick = id;
      bricks_.addBrick(bi, bj, bk);
    }
  });
}

}  // namespace pp5::gp
