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

__attribute__((target("avx,f16c"))) void floatToHalf4F16c(const std::byte* src, std::size_t stride, std::size_t count,
                                                          std::byte* dst) {
  for (std::size_t g = 0; g < count; ++g)
    _mm_storel_epi64(reinterpret_cast<__m128i*>(dst + 8 * g),
                     _mm_cvtps_ph(_mm_loadu_ps(reinterpret_cast<const float*>(src + g * stride)),
                                  _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
}

__attribute__((target("avx,f16c"))) void halfToFloat4F16c(const std::byte* src, std::size_t count, std::byte* dst,
                                                          std::size_t stride) {
  for (std::size_t g = 0; g < count; ++g)
    _mm_storeu_ps(reinterpret_cast<float*>(dst + g * stride),
                  _mm_cvtph_ps(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(src + 8 * g))));
}

}  // namespace

void floatToHalf4Strided(const void* src, std::size_t strideBytes, std::size_t count, void* dst) {
  const auto* in = static_cast<const std::byte*>(src);
  auto* out = static_cast<std::byte*>(dst);
  if (halfConversionUsesF16c()) return floatToHalf4F16c(in, strideBytes, count, out);
  for (std::size_t g = 0; g < count; ++g) {
    float v[4];
    std::memcpy(v, in + g * strideBytes, sizeof v);
    const std::uint16_t h[4] = {floatToHalf(v[0]), floatToHalf(v[1]), floatToHalf(v[2]), floatToHalf(v[3])};
    std::memcpy(out + 8 * g, h, sizeof h);
  }
}

void halfToFloat4Strided(const void* src, std::size_t count, void* dst, std::size_t strideBytes) {
  const auto* in = static_cast<const std::byte*>(src);
  auto* out = static_cast<std::byte*>(dst);
  if (halfConversionUsesF16c()) return halfToFloat4F16c(in, count, out, strideBytes);
  for (std::size_t g = 0; g < count; ++g) {
    std::uint16_t h[4];
    std::memcpy(h, in + 8 * g, sizeof h);
    const float v[4] = {halfToFloat(h[0]), halfToFloat(h[1]), halfToFloat(h[2]), halfToFloat(h[3])};
    std::memcpy(out + g * strideBytes, v, sizeof v);
  }
}

void halfToFloatN(const std::uint16_t* src, std::size_t n, float* dst) {
  if (halfConversionUsesF16c()) return halfToFloatF16c(src, n, dst);
  for (std::size_t i = 0; i < n; ++i) dst[i] = halfToFloat(src[i]);
}

void floatToHalfN(const float* src, std::size_t n, std::uint16_t* dst) {
  if (halfConversionUsesF16c()) return floatToHalfF16c(src, n, dst);
  for (std::size_t i = 0; i < n; ++i) dst[i] = floatToHalf(src[i]);
}

}  // namespace pp5
