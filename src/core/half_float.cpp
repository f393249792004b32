#include "core/half_float.hpp"

#include <immintrin.h>

namespace pp5 {

// Half conversions. F16C converts 8 values an instruction; the target
// attribute confines AVX to these functions (and to the half put loop), so
// nothing else, FMA contraction included, changes with the CPU.

namespace {

__attribute__((target("avx,f16c"))) void halfToFloatF16c(const std::uint16_t* src, std::size_t n, float* dst) {
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8)
    _mm256_storeu_ps(dst + i, _mm256_cvtph_ps(_mm_loadu_si128(reinterpret_cast<const __m128i*>(src + i))));
  for (; i < n; ++i) dst[i] = halfToFloat(src[i]);
}

__attribute__((target("avx,f16c"))) void floatToHalfF16c(const float* src, std::size_t n, std::uint16_t* dst) {
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8)
    _mm_storeu_si128(reinterpret_cast<__m128i*>(dst + i),
                     _mm256_cvtps_ph(_mm256_loadu_ps(src + i), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
  for (; i < n; ++i) dst[i] = floatToHalf(src[i]);
}

}  // namespace

void halfToFloatN(const std::uint16_t* src, std::size_t n, float* dst) {
  if (halfConversionUsesF16c()) return halfToFloatF16c(src, n, dst);
  for (std::size_t i = 0; i < n; ++i) dst[i] = halfToFloat(src[i]);
}

void floatToHalfN(const float* src, std::size_t n, std::uint16_t* dst) {
  if (halfConversionUsesF16c()) return floatToHalfF16c(src, n, dst);
  for (std::size_t i = 0; i < n; ++i) dst[i] = floatToHalf(src[i]);
}

}  // namespace pp5
