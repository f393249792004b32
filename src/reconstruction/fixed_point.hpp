#pragma once
// PLUS's own number formats, for the "plus" arithmetic of the pixel methods
// (docs/notes/plus-reconstruction.md, sections 3.1 and 3.2):
//  - `fixed`: a 32-bit integer with 14 fractional bits, used by PLUS's FULL
//    optimisation for pixel positions and trilinear weights;
//  - igsioMath::Floor / Round, which first round their argument to a multiple
//    of 2^-16, so values a hair below an integer count as that integer.
// Everything is written with plain integer and double arithmetic so that no
// libm rounding call (absent on baseline x86-64 without SSE4.1) sits in the
// inner loops.
#include <cstdint>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace pp5::gp::plusmath {

inline constexpr int kFracBits = 14;
inline constexpr std::int32_t kOne = std::int32_t{1} << kFracBits;
inline constexpr std::int32_t kHalf = kOne / 2;

// Nearest integer, ties to even, for |x| < 2^51, in the default rounding
// mode: adding 1.5 * 2^52 leaves no fractional bits, so the FPU rounds.
// (Not folded away: without -ffast-math the compiler must keep both steps.)
inline double roundHalfEven(double x) {
  constexpr double kMagic = 6755399441055744.0;
  return (x + kMagic) - kMagic;
}

// The same as an integer, in one instruction where there is one (SSE2's
// conversion rounds by the current mode: ties to even unless changed).
inline std::int64_t nearestInt(double x) {
#if defined(__SSE2__)
  return _mm_cvtsd_si64(_mm_set_sd(x));
#else
  return static_cast<std::int64_t>(roundHalfEven(x));
#endif
}

// Largest |value| a fixed number can hold without wrapping.
inline constexpr double kFixedLimit = 131071.0;

// double -> fixed: the nearest multiple of 2^-14, ties to even (PLUS adds a
// magic constant, which rounds the same way). The caller keeps |x| below
// kFixedLimit.
inline std::int32_t toFixed(double x) { return static_cast<std::int32_t>(nearestInt(x * double(kOne))); }
inline double toDouble(std::int32_t raw) { return raw * (1.0 / double(kOne)); }

// fixed * fixed, rounded half up to 2^-14 (PLUS computes this in int32; the
// operands used here never overflow it).
inline std::int32_t mul(std::int32_t a, std::int32_t b) {
  return static_cast<std::int32_t>((std::int64_t{a} * b + kHalf) >> kFracBits);
}
// fixed / fixed: the quotient rounded to double, then to the nearest 2^-14.
inline std::int32_t div(std::int32_t a, std::int32_t b) { return toFixed(double(a) / double(b)); }
// floor(v + 1/2) and floor(v) of a fixed value, as integers.
inline std::int32_t roundToInt(std::int32_t raw) { return (raw + kHalf) >> kFracBits; }
inline std::int32_t floorToInt(std::int32_t raw) { return raw >> kFracBits; }

// floor(n / k) for n < 2^16 and 1 <= k <= 255, without a division: with
// r = floor(2^32 / k) + 1, (n * r) >> 32 overshoots n / k by
// n * (r*k - 2^32) / (k * 2^32) < 1/k, so the floor is exact (tested for
// every n and k). PLUS's nearest-neighbour running mean divides by such k.
struct SmallReciprocals {
  std::uint64_t r[256];
  constexpr SmallReciprocals() : r{} {
    for (int k = 1; k < 256; ++k) r[k] = (std::uint64_t{1} << 32) / static_cast<std::uint64_t>(k) + 1;
  }
};
inline constexpr SmallReciprocals kSmallReciprocals{};
inline std::uint32_t divSmall(std::uint32_t n, std::uint32_t k) {
  return static_cast<std::uint32_t>((std::uint64_t{n} * kSmallReciprocals.r[k]) >> 32);
}

// igsioMath::Floor: floor of x rounded (ties to even) to a multiple of 2^-16.
inline std::int64_t floorPlus(double x) {
  return static_cast<std::int64_t>(roundHalfEven(x * 65536.0)) >> 16;
}
// The fan code's ceiling, written -Floor(-x) in PLUS.
inline std::int64_t ceilPlus(double x) { return -floorPlus(-x); }

}  // namespace pp5::gp::plusmath
