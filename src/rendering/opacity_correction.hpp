#pragma once
// The opacity correction for the sampling step: a' = 1 - (1 - a)^e, four
// samples at a time, as a polynomial log2/exp2 in float (relative error
// about 1e-6), the same bits on any machine, unlike libm's powf.
#include "core/simd.hpp"

namespace pp5::gp {

namespace opacity {

using namespace pp5::simd;

// a' = 1 - (1 - a)^e for a in [0, 1], e > 0, e != 1.
// log2(1 - a) by the atanh series on the mantissa m: where m is 1 - a itself
// (a < 1 - 2^-0.5) the series' argument is formed from a, not from the rounded
// 1 - a, so small opacities keep their relative precision. The power is then
// 2^n (1 + expm1(f)) with n the nearest integer, and a' = (1 - 2^n) - 2^n
// expm1(f): for n = 0 that is exactly -expm1(f), again without cancellation.
// Relative error about 1e-6 over the whole range.
inline F4 correct4(F4 a, float e) {
  const F4 one = splat(1.0f);
  F4 x = one - a;
  x = select(x < splat(1e-30f), splat(1e-30f), x);  // a >= 1: fixed below
  const I4 bits = reinterpret_cast<I4>(x);
  I4 ex = (bits >> 23) - splatI(127);
  F4 m = reinterpret_cast<F4>((bits & splatI(0x007fffff)) | splatI(0x3f800000));
  const I4 big = m > splat(1.41421356f);
  m = select(big, m * splat(0.5f), m);
  ex = ex - big;  // big is -1 where true
  const I4 own = ex == splatI(0);
  const F4 num = select(own, -a, m - one);
  const F4 den = select(own, splat(2.0f) - a, m + one);
  const F4 s = num / den, s2 = s * s;
  const F4 ln =
      splat(2.0f) * s *
      (one + s2 * (splat(1.0f / 3) + s2 * (splat(1.0f / 5) + s2 * (splat(1.0f / 7) + s2 * splat(1.0f / 9)))));
  F4 y = splat(e) * (__builtin_convertvector(ex, F4) + ln * splat(1.44269504f));
  y = select(y < splat(-126.0f), splat(-126.0f), y);
  // Nearest integer without the FPU's rounding mode: y <= 0.
  const I4 n = -__builtin_convertvector(splat(0.5f) - y, I4);
  const F4 z = (y - __builtin_convertvector(n, F4)) * splat(0.693147181f);
  const F4 em1 =
      z * (one + z * (splat(1.0f / 2) +
                      z * (splat(1.0f / 6) +
                           z * (splat(1.0f / 24) + z * (splat(1.0f / 120) + z * (splat(1.0f / 720) + z * splat(1.0f / 5040)))))));
  const F4 p2n = reinterpret_cast<F4>((n + splatI(127)) << 23);
  F4 ap = (one - p2n) - p2n * em1;
  ap = select(a >= one, one, ap);
  return select(a > splat(0.0f), ap, splat(0.0f));
}

inline F4 correctLanes(F4 a, float e) {
  if (e == 1.0f) return select(a >= splat(1.0f), splat(1.0f), select(a > splat(0.0f), a, splat(0.0f)));
  return correct4(a, e);
}

}  // namespace opacity

// 1 - (1 - a)^e for a in [0, 1], e > 0: the opacity correction, as the
// sampler computes it.
inline float correctOpacity(float a, float e) { return opacity::correctLanes(simd::F4{a, 0.0f, 0.0f, 0.0f}, e)[0]; }

}  // namespace pp5::gp
