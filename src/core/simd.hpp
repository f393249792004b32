#pragma once
// The four-lane float vocabulary of the stages, one header for all of them:
//  - F4 / I4: GCC vector extensions, so the same IEEE operations run whatever
//    the instruction set (SSE2 here) and one lane computed alone gives the bits
//    of the same lane in a batch (the sampler, the opacity correction, the
//    trilinear pixel kernels);
//  - Float4: a class with the lane shuffles the tent kernel's profiles need.
#include <algorithm>
#include <cmath>
#include <cstdint>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace pp5::simd {

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

// Four float lanes as a small class with the lane shuffles the tent kernel
// needs: SSE2 where there is one, else plain floats with the same operations
// in the same order per lane, so the results do not depend on it.
struct Float4 {
#if defined(__SSE2__)
  __m128 v;
  static Float4 set1(float x) { return {_mm_set1_ps(x)}; }
  static Float4 zero() { return {_mm_setzero_ps()}; }
  static Float4 load(const float* p) { return {_mm_loadu_ps(p)}; }
  void store(float* p) const { _mm_storeu_ps(p, v); }
  friend Float4 operator+(Float4 a, Float4 b) { return {_mm_add_ps(a.v, b.v)}; }
  friend Float4 operator-(Float4 a, Float4 b) { return {_mm_sub_ps(a.v, b.v)}; }
  friend Float4 operator*(Float4 a, Float4 b) { return {_mm_mul_ps(a.v, b.v)}; }
  static Float4 abs(Float4 a) { return {_mm_andnot_ps(_mm_set1_ps(-0.0f), a.v)}; }
  static Float4 max0(Float4 a) { return {_mm_max_ps(a.v, _mm_setzero_ps())}; }
  // Lane L in every lane.
  template <int L>
  static Float4 lane(Float4 a) { return {_mm_shuffle_ps(a.v, a.v, L * 0x55)}; }
  // Lanes 2 and 3 in lanes 0 and 1 (and again in 2 and 3).
  static Float4 high(Float4 a) { return {_mm_movehl_ps(a.v, a.v)}; }
  // (a0, a1, b0, b1)
  static Float4 halves(Float4 a, Float4 b) { return {_mm_movelh_ps(a.v, b.v)}; }
  // lo = (a0, b0, a1, b1), hi = (a2, b2, a3, b3)
  static void interleave(Float4 a, Float4 b, Float4& lo, Float4& hi) {
    lo.v = _mm_unpacklo_ps(a.v, b.v);
    hi.v = _mm_unpackhi_ps(a.v, b.v);
  }
  float lane0() const { return _mm_cvtss_f32(v); }
  float lane1() const { return _mm_cvtss_f32(_mm_shuffle_ps(v, v, 1)); }
#else
  float l[4];
  template <typename Op>
  static Float4 map(Float4 a, Float4 b, Op op) {
    return {{op(a.l[0], b.l[0]), op(a.l[1], b.l[1]), op(a.l[2], b.l[2]), op(a.l[3], b.l[3])}};
  }
  static Float4 set1(float x) { return {{x, x, x, x}}; }
  static Float4 zero() { return set1(0.0f); }
  static Float4 load(const float* p) { return {{p[0], p[1], p[2], p[3]}}; }
  void store(float* p) const { std::copy_n(l, 4, p); }
  friend Float4 operator+(Float4 a, Float4 b) { return map(a, b, [](float x, float y) { return x + y; }); }
  friend Float4 operator-(Float4 a, Float4 b) { return map(a, b, [](float x, float y) { return x - y; }); }
  friend Float4 operator*(Float4 a, Float4 b) { return map(a, b, [](float x, float y) { return x * y; }); }
  static Float4 abs(Float4 a) { return map(a, a, [](float x, float) { return std::fabs(x); }); }
  static Float4 max0(Float4 a) { return map(a, a, [](float x, float) { return x > 0.0f ? x : 0.0f; }); }
  template <int L>
  static Float4 lane(Float4 a) { return set1(a.l[L]); }
  static Float4 high(Float4 a) { return {{a.l[2], a.l[3], a.l[2], a.l[3]}}; }
  static Float4 halves(Float4 a, Float4 b) { return {{a.l[0], a.l[1], b.l[0], b.l[1]}}; }
  static void interleave(Float4 a, Float4 b, Float4& lo, Float4& hi) {
    lo = {{a.l[0], b.l[0], a.l[1], b.l[1]}};
    hi = {{a.l[2], b.l[2], a.l[3], b.l[3]}};
  }
  float lane0() const { return l[0]; }
  float lane1() const { return l[1]; }
#endif
};

}  // namespace pp5::simd
