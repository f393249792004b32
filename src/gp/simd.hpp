#pragma once
// The GP stages' four-lane float vocabulary: GCC vector extensions, so the
// same IEEE operations run whatever the instruction set (SSE2 here) and one
// lane computed alone gives the bits of the same lane in a batch.
#include <cstdint>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace pp5::gp::simd {

typedef float F4 __attribute__((vector_size(16)));
typedef std::int32_t I4 __attribute__((vector_size(16)));

inline F4 splat(float v) { return F4{v, v, v, v}; }
inline I4 splatI(std::int32_t v) { return I4{v, v, v, v}; }
inline F4 select(I4 mask, F4 a, F4 b) { return reinterpret_cast<F4>((mask & reinterpret_cast<I4>(a)) | (~mask & reinterpret_cast<I4>(b))); }
// Lane-wise min and max as std::min/std::max order them (second operand on
// ties and NaN), so the scalar path gives the same cells.
inline F4 vmin(F4 a, F4 b) {
#if defined(__SSE2__)
  return reinterpret_cast<F4>(_mm_min_ps(reinterpret_cast<__m128>(b), reinterpret_cast<__m128>(a)));
#else
  return select(b < a, b, a);
#endif
}
inline F4 vmax(F4 a, F4 b) {
#if defined(__SSE2__)
  return reinterpret_cast<F4>(_mm_max_ps(reinterpret_cast<__m128>(b), reinterpret_cast<__m128>(a)));
#else
  return select(a < b, b, a);
#endif
}

inline bool anyPositive(F4 a) {
#if defined(__SSE2__)
  return _mm_movemask_ps(_mm_cmpgt_ps(reinterpret_cast<__m128>(a), _mm_setzero_ps())) != 0;
#else
  return a[0] > 0.0f || a[1] > 0.0f || a[2] > 0.0f || a[3] > 0.0f;
#endif
}

}  // namespace pp5::gp::simd
