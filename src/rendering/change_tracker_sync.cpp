// The change tracker's set-up and full re-sync (after a view or shading
// change, the final passes): its copy of the volume, its cells, the largest
// value of each row.
#include "rendering/change_tracker.hpp"

#include <algorithm>
#include <bit>
#include <climits>
#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>
#include "core/error.hpp"
#include "reconstruction/voxel_array.hpp"
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include "rendering/change_tracker_detail.hpp"

namespace pp5::gp {

namespace {

// The largest of n values (a NaN counts as infinity; -infinity when n is 0).
template <class T>
float largestOf(const std::uint8_t* bytes, std::int64_t n) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  float m = -kInf;
  std::int64_t x = 0;
#if defined(__SSE2__)
  if constexpr (std::is_same_v<T, float>) {
    // max(v, m) takes m where v is NaN; the NaNs are noted apart.
    __m128 m4 = _mm_set1_ps(-kInf), nan4 = _mm_setzero_ps();
    for (; x + 4 <= n; x += 4) {
      const __m128 q = _mm_loadu_ps(reinterpret_cast<const float*>(bytes) + x);
      nan4 = _mm_or_ps(nan4, _mm_cmpunord_ps(q, q));
      m4 = _mm_max_ps(q, m4);
    }
    if (_mm_movemask_ps(nan4)) return kInf;
    float lanes[4];
    _mm_storeu_ps(lanes, m4);
    m = std::max(std::max(lanes[0], lanes[1]), std::max(lanes[2], lanes[3]));
  }
#endif
  for (; x < n; ++x) {
    const float v = loadValue<T>(bytes, x);
    if (!(v <= m)) m = std::isnan(v) ? kInf : v;
  }
  return m;
}

// A zero-filled (or copied) byte array on huge pages where the system allows:
// the tracker reads rows a kilobyte apart, a TLB miss a row on 4 KiB pages.
template <typename It>
void assignOnHugePages(std::vector<std::uint8_t>& v, It first, It last) {
  v.reserve(static_cast<std::size_t>(last - first));
  adviseHugePages(v.data(), v.capacity());
  v.assign(first, last);
}
}  // namespace

ChangeTracker::ChangeTracker(const Volume& values, const ShadeBuffer& shades, bool compare)
    : grid_(values.grid),
      type_(values.type),
      compare_(compare),
      ranges_(static_cast<std::size_t>(values.grid.dims.y * values.grid.dims.z), RowRanges{kNone, -1, kNone, -1}),
      bricks_(values.grid, kBrick) {
  copy_.grid = values.grid;
  copy_.type = values.type;
  const std::vector<std::uint8_t> zero(values.grid.voxelCount(), 0);
  assignOnHugePages(cells_, zero.begin(), zero.end());
  resync(values, shades);
}

std::uint64_t ChangeTracker::memoryBytes(const Grid& g, ScalarType t, bool compare) {
  const std::uint64_t n = g.voxelCount();
  const std::uint64_t values = compare ? n * static_cast<std::uint64_t>(scalarBytes(t)) : (n + 63) / 64 * 8;
  // Per row: the four ranges' ends, and without the copy the row's bound and mark.
  return n + values + static_cast<std::uint64_t>(g.dims.y * g.dims.z) * (compare ? 16 : 21);
}

void ChangeTracker::resync(const Volume& values, const ShadeBuffer& shades) {
  PP5_CHECK(values.grid.dims == grid_.dims);
  PP5_CHECK(values.type == type_);
  PP5_CHECK(shades.grid().dims == grid_.dims);
  if (compare_) {
    if (copy_.bytes.empty())
      assignOnHugePages(copy_.bytes, values.bytes.begin(), values.bytes.end());
    else
      copy_.bytes = values.bytes;
    return;
  }
  // Both passes read the whole grid once (as the copy did), four at a time.
  const std::uint64_t n = grid_.voxelCount();
  const Index3 d = grid_.dims;
  rowMax_.resize(static_cast<std::size_t>(d.y * d.z));
  const std::int64_t B = scalarBytes(values.type);
  for (std::int64_t r = 0; r < d.y * d.z; ++r) {
    const std::uint8_t* row = values.bytes.data() + r * d.x * B;
    float m = 0.0f;
    switch (values.type) {
      case ScalarType::U8: m = largestOf<std::uint8_t>(row, d.x); break;
      case ScalarType::U16: m = largestOf<std::uint16_t>(row, d.x); break;
      case ScalarType::F32: m = largestOf<float>(row, d.x); break;
    }
    rowMax_[static_cast<std::size_t>(r)] = m;
  }
  shadedBits_.assign((n + 63) / 64, 0);
  const auto* v = reinterpret_cast<const std::uint8_t*>(shades.data());
  for (std::uint64_t w = 0; w < shadedBits_.size(); ++w) {
    std::uint64_t bits = 0;
    const std::uint64_t end = std::min<std::uint64_t>(64, n - 64 * w);
    std::uint64_t b = 0;
#if defined(__SSE2__)
    // A shade is zero when its four bytes are: four shades a compare.
    for (; b + 4 <= end; b += 4) {
      const __m128i q = _mm_loadu_si128(reinterpret_cast<const __m128i*>(v + 4 * (64 * w + b)));
      const auto zero = static_cast<unsigned>(_mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(q, _mm_setzero_si128()))));
      bits |= static_cast<std::uint64_t>(zero ^ 0xfu) << b;
    }
#endif
    for (; b < end; ++b) {
      std::uint32_t rgba;
      std::memcpy(&rgba, v + 4 * (64 * w + b), 4);
      bits |= static_cast<std::uint64_t>(rgba != 0) << b;
    }
    shadedBits_[w] = bits;
  }
}

}  // namespace pp5::gp
