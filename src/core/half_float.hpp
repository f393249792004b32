#pragma once
#include <cstddef>
#include <cstdint>
#include <cstring>
#if defined(__x86_64__) || defined(__i386__)
#include <cpuid.h>
#endif

namespace pp5 {

// IEEE binary16 conversions used by the half format, bit-identical to GCC's
// _Float16 conversions (round to nearest even; subnormals, inf and NaN kept).
// Written out because without F16C the compiler calls libgcc for each value;
// branch-free, since zero and subnormal values are common in sample data and
// a branch on them mispredicts.
inline std::uint16_t floatToHalf(float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, 4);
  const std::uint32_t sign = (u >> 16) & 0x8000u;
  u &= 0x7fffffffu;
  // Normal: rebias the exponent (-112 << 23, mod 2^32), round to nearest even.
  const std::uint32_t normal = (u + 0xc8000fffu + ((u >> 13) & 1u)) >> 13;
  // Below half's smallest normal: adding 0.5 (ulp 2^-24, half's subnormal
  // step) makes the FPU round to the subnormal grid.
  float a;
  std::memcpy(&a, &u, 4);
  a += 0.5f;
  std::uint32_t v;
  std::memcpy(&v, &a, 4);
  const std::uint32_t sub = v - 0x3f000000u;
  // 65520 and above round to inf; NaN stays NaN, quiet.
  const std::uint32_t big = u > 0x7f800000u ? (0x7e00u | ((u >> 13) & 0x3ffu)) : 0x7c00u;
  const std::uint32_t h = u >= 0x47800000u ? big : u < 0x38800000u ? sub : normal;
  return static_cast<std::uint16_t>(h | sign);
}

inline float halfToFloat(std::uint16_t h) {
  const std::uint32_t m = static_cast<std::uint32_t>(h & 0x7fffu) << 13;
  const std::uint32_t e = m & 0x0f800000u;
  const std::uint32_t isSub = 0u - static_cast<std::uint32_t>(e == 0);
  const std::uint32_t isInf = 0u - static_cast<std::uint32_t>(e == 0x0f800000u);
  const std::uint32_t normal = m + (112u << 23) + (isInf & (112u << 23));
  // Zero and subnormals through a normal float, never a subnormal one (slow on x86).
  const std::uint32_t v = m + (113u << 23), magicBits = 113u << 23;
  float fv, magic;
  std::memcpy(&fv, &v, 4);
  std::memcpy(&magic, &magicBits, 4);
  const float sub = fv - magic;
  std::uint32_t subBits;
  std::memcpy(&subBits, &sub, 4);
  const std::uint32_t u = (isSub & subBits) | (~isSub & normal) | (static_cast<std::uint32_t>(h & 0x8000u) << 16);
  float f;
  std::memcpy(&f, &u, 4);
  return f;
}

// n values at once: F16C instructions where the CPU has them (checked once),
// else the functions above; the same bits either way.
void halfToFloatN(const std::uint16_t* src, std::size_t n, float* dst);
void floatToHalfN(const float* src, std::size_t n, std::uint16_t* dst);
// `count` groups of 4 values: group g's floats at src + g * strideBytes, its
// halves at dst + 8 * g (contiguous). The four channels of a sample kept in a
// struct, to or from a packed wire; addresses are in bytes, so that a
// caller steps through an array of structs, not past a member. The same bits
// as the one-value functions, with F16C or without, but for a signalling NaN
// half, which F16C turns into a quiet one (no pp5echo wire holds one).
void floatToHalf4Strided(const void* src, std::size_t strideBytes, std::size_t count, void* dst);
void halfToFloat4Strided(const void* src, std::size_t count, void* dst, std::size_t strideBytes);
// Whether the CPU converts with F16C (and AVX), which the N-value conversions
// and the cache's half put loop then use. A function-local static, so that it
// is set even when called during another file's static initialisation.
// CPUID leaf 1 (ECX: OSXSAVE bit 27, AVX 28, F16C 29) and XGETBV (the OS saves
// the YMM registers), which GCC and clang both compile (clang 14's
// __builtin_cpu_supports does not know "f16c").
inline bool halfConversionUsesF16c() {
  static const bool has = [] {
#if defined(__x86_64__) || defined(__i386__)
    unsigned a = 0, b = 0, c = 0, d = 0;
    if (!__get_cpuid(1, &a, &b, &c, &d)) return false;
    const unsigned need = (1u << 27) | (1u << 28) | (1u << 29);
    if ((c & need) != need) return false;
    unsigned lo = 0, hi = 0;
    __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
    return (lo & 6u) == 6u;
#else
    return false;
#endif
  }();
  return has;
}

}  // namespace pp5
