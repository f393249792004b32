#include "gp/change_tracker.hpp"

#include <algorithm>
#include <bit>
#include <climits>
#include <cstring>
#include <type_traits>

#include "core/error.hpp"
#include "gp/voxel_array.hpp"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace pp5::gp {

namespace {
constexpr std::int32_t kNone = INT32_MAX;
constexpr std::int64_t kAhead = 8;  // rows fetched ahead
}

namespace {
// A zero-filled (or copied) byte array on huge pages where the system allows:
// the tracker reads rows a kilobyte apart, a TLB miss a row on 4 KiB pages.
template <typename It>
void assignOnHugePages(std::vector<std::uint8_t>& v, It first, It last) {
  v.reserve(static_cast<std::size_t>(last - first));
  adviseHugePages(v.data(), v.capacity());
  v.assign(first, last);
}
}  // namespace

ChangeTracker::ChangeTracker(const Volume& values)
    : grid_(values.grid),
      rowLo_(static_cast<std::size_t>(values.grid.dims.y * values.grid.dims.z), kNone),
      rowHi_(static_cast<std::size_t>(values.grid.dims.y * values.grid.dims.z), -1),
      selfLo_(rowLo_),
      selfHi_(rowHi_),
      visLo_(rowLo_),
      visHi_(rowHi_),
      bricks_(values.grid, kBrick) {
  copy_.grid = values.grid;
  copy_.type = values.type;
  assignOnHugePages(copy_.bytes, values.bytes.begin(), values.bytes.end());
  const std::vector<std::uint8_t> zero(values.grid.voxelCount(), 0);
  assignOnHugePages(cells_, zero.begin(), zero.end());
}

std::uint64_t ChangeTracker::memoryBytes(const Grid& g, ScalarType t) {
  return g.voxelCount() * bytesPerVoxel(t) +
         static_cast<std::uint64_t>(g.dims.y * g.dims.z) * 32;
}

void ChangeTracker::resync(const Volume& values) {
  PP5_CHECK(values.grid.dims == grid_.dims);
  PP5_CHECK(values.type == copy_.type);
  copy_.bytes = values.bytes;
}

namespace {

// One row's ranges (lo > hi: none), x relative to the row's first voxel.
struct RowScan {
  std::int32_t changedLo = kNone, changedHi = -1;  // values that changed
  std::int32_t selfLo = kNone, selfHi = -1;        // ... and were or are visible
  std::int32_t visibleLo = kNone, visibleHi = -1;  // values visible now
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
    const bool vis = visible(now);
    if (vis) {
      s.visibleLo = std::min(s.visibleLo, v);
      s.visibleHi = v;
    }
    if (now == was) continue;
    s.changedLo = std::min(s.changedLo, v);
    s.changedHi = v;
    if (vis || visible(was)) {
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
// scanRow for float values, four at a time without a branch per voxel (the
// speckle of a reconstruction makes "visible" a coin toss, which a branch
// mispredicts): the same tests by the same float operations, so the same
// ranges.
RowScan scanRowF32(const std::uint8_t* nowBytes, std::uint8_t* wasBytes, std::int32_t n, const TransferFunction* tf) {
  RowScan s;
  const __m128 zero = _mm_setzero_ps(), top = _mm_set1_ps(255.0f);
  const __m128 steps = _mm_set1_ps(static_cast<float>(TransferFunction::kStepsPerLevel));
  const __m128 below = _mm_set1_ps(tf ? tf->transparentBelow() : 0.0f);
  // Lanes visible by transparentUpTo's test: x = v <= 0 ? 0 : v >= 255 ? 255
  // : v, visible unless x * steps < below (a NaN stays visible, as there).
  auto visible = [&](__m128 v) -> int {
    if (!tf) return 0xf;
    const __m128 le = _mm_cmple_ps(v, zero), ge = _mm_cmpge_ps(v, top);
    const __m128 clamped = _mm_or_ps(_mm_and_ps(ge, top), _mm_andnot_ps(ge, v));
    const __m128 x = _mm_andnot_ps(le, clamped);
    return _mm_movemask_ps(_mm_cmplt_ps(_mm_mul_ps(x, steps), below)) ^ 0xf;
  };
  auto note = [](std::int32_t& lo, std::int32_t& hi, int mask, std::int32_t at) {
    if (!mask) return;
    lo = std::min(lo, at + std::countr_zero(static_cast<unsigned>(mask)));
    hi = at + 31 - std::countl_zero(static_cast<unsigned>(mask));
  };
  std::int32_t v = 0;
  for (; v + 4 <= n; v += 4) {
    const __m128i nowI = _mm_loadu_si128(reinterpret_cast<const __m128i*>(nowBytes + 4 * v));
    const __m128i wasI = _mm_loadu_si128(reinterpret_cast<const __m128i*>(wasBytes + 4 * v));
    const int changed = _mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(nowI, wasI))) ^ 0xf;
    const int vis = visible(_mm_castsi128_ps(nowI));
    note(s.visibleLo, s.visibleHi, vis, v);
    if (!changed) continue;
    note(s.changedLo, s.changedHi, changed, v);
    note(s.selfLo, s.selfHi, changed & (vis | visible(_mm_castsi128_ps(wasI))), v);
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
    widen(s.visibleLo, s.visibleHi, t.visibleLo, t.visibleHi);
  }
  // The copy takes the changed range (the tail's part again, the same bytes).
  if (s.changedLo <= s.changedHi)
    std::memcpy(wasBytes + 4 * s.changedLo, nowBytes + 4 * s.changedLo,
                static_cast<std::size_t>(s.changedHi - s.changedLo + 1) * 4);
  return s;
}
#endif

}  // namespace

std::vector<Box3> ChangeTracker::shadingRuns(const Volume& values, std::span<const Box3> dirty,
                                             std::span<const Box3> within, const TransferFunction* tf) {
  PP5_CHECK(values.grid.dims == grid_.dims);
  PP5_CHECK(values.type == copy_.type);
  const Index3 d = grid_.dims;
  const ScalarType type = values.type;
  const std::int64_t B = scalarBytes(type);
  const Box3 all{Index3(0), d};
  auto widen = [](std::int32_t& lo, std::int32_t& hi, std::int32_t a, std::int32_t z, std::int64_t x0) {
    if (a > z) return;
    lo = std::min(lo, static_cast<std::int32_t>(x0 + a));
    hi = std::max(hi, static_cast<std::int32_t>(x0 + z));
  };
  // One pass over the values: what changed, and what is visible (the rows
  // next to a change need it too, so every row of `dirty` is scanned).
  for (const Box3& b0 : dirty) {
    const Box3 b = b0.intersect(all);
    if (b.empty()) continue;
    const std::int64_t len = (b.hi.x - b.lo.x) * B;
    const auto n = static_cast<std::int32_t>(b.hi.x - b.lo.x);
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
        if (r.changedLo > r.changedHi && r.visibleLo > r.visibleHi) continue;
        const auto i = static_cast<std::size_t>(row);
        if (rowLo_[i] > rowHi_[i] && selfLo_[i] > selfHi_[i] && visLo_[i] > visHi_[i]) rowsTouched_.push_back(row);
        widen(rowLo_[i], rowHi_[i], r.changedLo, r.changedHi, b.lo.x);
        widen(selfLo_[i], selfHi_[i], r.selfLo, r.selfHi, b.lo.x);
        widen(visLo_[i], visHi_[i], r.visibleLo, r.visibleHi, b.lo.x);
      }
  }
  std::vector<Box3> out;
  bool any = false;
  for (const std::int64_t row : rowsTouched_) any = any || rowLo_[static_cast<std::size_t>(row)] <= rowHi_[static_cast<std::size_t>(row)];
  if (any) {
    for (const Box3& w0 : within) {
      const Box3 w = w0.intersect(all);
      if (w.empty()) continue;
      for (std::int64_t k = w.lo.z; k < w.hi.z; ++k)
        for (std::int64_t j = w.lo.y; j < w.hi.y; ++j) {
          // The row and its four face-neighbour rows: a voxel reads x - 1 and
          // x + 1 of its own row and x of the others.
          std::int32_t lo = kNone, hi = -1;
          auto take = [&](std::int64_t jj, std::int64_t kk) {
            if (jj < 0 || jj >= d.y || kk < 0 || kk >= d.z) return;
            const auto r = static_cast<std::size_t>(kk * d.y + jj);
            lo = std::min(lo, rowLo_[r]);
            hi = std::max(hi, rowHi_[r]);
          };
          take(j, k);
          take(j - 1, k);
          take(j + 1, k);
          take(j, k - 1);
          take(j, k + 1);
          if (lo > hi) continue;
          // Of the voxels next to a change, the visible ones (this row's
          // visible range, so a few more); and this row's own changes that
          // were or are visible.
          const auto r = static_cast<std::size_t>(k * d.y + j);
          std::int32_t a = std::max(lo - 1, visLo_[r]), z = std::min(hi + 1, visHi_[r]);
          if (a > z) {
            a = selfLo_[r];
            z = selfHi_[r];
          } else if (selfLo_[r] <= selfHi_[r]) {
            a = std::min(a, selfLo_[r]);
            z = std::max(z, selfHi_[r]);
          }
          const std::int64_t s0 = std::max<std::int64_t>(a, w.lo.x), s1 = std::min<std::int64_t>(z, w.hi.x - 1);
          if (s0 <= s1) out.push_back({Index3(s0, j, k), Index3(s1 + 1, j + 1, k + 1)});
        }
    }
  }
  for (const std::int64_t row : rowsTouched_) {
    const auto r = static_cast<std::size_t>(row);
    rowLo_[r] = selfLo_[r] = visLo_[r] = kNone;
    rowHi_[r] = selfHi_[r] = visHi_[r] = -1;
  }
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
  std::int64_t rowBase_ = -1, j_ = 0, k_ = 0;
};
}  // namespace

void ChangeTracker::markCells(std::uint8_t value) {
  const Index3 d = grid_.dims;
  RowCursor cur(d);
  for (const std::int64_t v : changed_) {
    std::int64_t i = 0, j = 0, k = 0;
    cur.at(v, i, j, k);
    // Voxel v is a corner of cells v - 1 and v on each axis (those in 0 .. dims - 2).
    for (std::int64_t ck = std::max<std::int64_t>(k - 1, 0); ck <= std::min(k, d.z - 2); ++ck)
      for (std::int64_t cj = std::max<std::int64_t>(j - 1, 0); cj <= std::min(j, d.y - 2); ++cj) {
        std::uint8_t* row = cells_.data() + (ck * d.y + cj) * d.x;
        for (std::int64_t ci = std::max<std::int64_t>(i - 1, 0); ci <= std::min(i, d.x - 2); ++ci) row[ci] = value;
      }
  }
}

void ChangeTracker::setShadeChanges(std::span<const std::int64_t> voxels) {
  for (const std::int64_t v : voxels) PP5_CHECK(v >= 0 && static_cast<std::uint64_t>(v) < grid_.voxelCount());
  markCells(0);
  changed_.assign(voxels.begin(), voxels.end());
  markCells(1);
  bricks_.clear();
  std::int64_t lastBrick = -1;
  RowCursor cur(grid_.dims);
  for (const std::int64_t v : changed_) {
    std::int64_t i = 0, j = 0, k = 0;
    cur.at(v, i, j, k);
    const std::int64_t bi = i / kBrick, bj = j / kBrick, bk = k / kBrick;
    const std::int64_t id = (bk * bricks_.brickDims().y + bj) * bricks_.brickDims().x + bi;
    if (id == lastBrick) continue;
    lastBrick = id;
    bricks_.addBrick(bi, bj, bk);
  }
}

}  // namespace pp5::gp
