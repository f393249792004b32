#pragma once
// Compositing kernels. One walk function serves composite(), a from-scratch
// render and compositeFull(): the same instructions in the same order, which
// is what makes incremental and full renders equal bit for bit.

//
// Internal to the ray cache (rendering/ray_cache.cpp), which instantiates them for
// each sample format and composition mode.
#include <algorithm>
#include <cstdint>
#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/half_float.hpp"
#include "rendering/ray_cache.hpp"

namespace pp5::pp::composite {

// Bounds the decode buffer each compositing thread keeps on its stack (render.cache.block_size).
constexpr int kMaxBlockSize = 1024;

// 0..1 to 0..255, rounded; NaN lands on 0 too.
inline std::uint8_t toU8(float v) {
  const float c = v > 0.0f ? (v < 1.0f ? v : 1.0f) : 0.0f;
  return static_cast<std::uint8_t>(c * 255.0f + 0.5f);
}

using Partial = RayCache::Partial;

// A block's state (RayCache::dirty_): its stored partial is valid; its
// samples changed since; or it has had no sample since the cache was reset
// or cleared, so it composites to the identity and its partial is not stored
// (a new view then writes a byte per block, not a partial).
constexpr std::uint8_t kBlockClean = 0, kBlockDirty = 1, kBlockTransparent = 2;

template <CompositeMode M>
constexpr Partial identityPartial() {
  if constexpr (M == CompositeMode::Over) return {0.f, 0.f, 0.f, 1.f};
  else return {0.f, 0.f, 0.f, 0.f};
}

inline Partial identityPartial(CompositeMode m) {
  switch (m) {
    case CompositeMode::Over: return identityPartial<CompositeMode::Over>();
    case CompositeMode::Additive: return identityPartial<CompositeMode::Additive>();
    case CompositeMode::Mip: return identityPartial<CompositeMode::Mip>();
  }
  return {};
}

// Folds the partial (r, g, b, w), which lies behind acc, into acc. For
// "over" a sample is the partial (r, g, b, 1 - a).
template <CompositeMode M>
inline void fold(Partial& acc, float r, float g, float b, float w) {
  if constexpr (M == CompositeMode::Over) {
    acc.r += acc.w * r;
    acc.g += acc.w * g;
    acc.b += acc.w * b;
    acc.w *= w;
  } else if constexpr (M == CompositeMode::Additive) {
    acc.r += r;
    acc.g += g;
    acc.b += b;
    acc.w += w;
  } else {
    acc.r = r > acc.r ? r : acc.r;
    acc.g = g > acc.g ? g : acc.g;
    acc.b = b > acc.b ? b : acc.b;
    acc.w = w > acc.w ? w : acc.w;
  }
}

template <SampleFormat F>
struct Storage;
template <>
struct Storage<SampleFormat::Rgba8> {
  using T = std::uint8_t;
};
template <>
struct Storage<SampleFormat::Half> {
  using T = std::uint16_t;
};
template <>
struct Storage<SampleFormat::Float> {
  using T = float;
};

// 4 * n stored values as floats; float storage is used in place.
template <SampleFormat F>
inline const float* decode(const typename Storage<F>::T* src, int n, float* scratch) {
  if constexpr (F == SampleFormat::Float) {
    return src;
  } else if constexpr (F == SampleFormat::Half) {
    halfToFloatN(src, 4 * static_cast<std::size_t>(n), scratch);
    return scratch;
  } else {
    for (int i = 0; i < 4 * n; ++i) scratch[i] = static_cast<float>(src[i]) * (1.0f / 255.0f);
    return scratch;
  }
}

template <CompositeMode M>
inline void foldSample(Partial& p, const float* s) {
  fold<M>(p, s[0], s[1], s[2], M == CompositeMode::Over ? 1.0f - s[3] : s[3]);
}

#if defined(__SSE2__)
// Four lanes at once, each a scalar fold<M> of its own samples: the same bits
// as the scalar loop below.
template <CompositeMode M>
inline void foldLanes(__m128& r, __m128& g, __m128& b, __m128& w, __m128 sr, __m128 sg, __m128 sb, __m128 sa) {
  if constexpr (M == CompositeMode::Over) {
    r = _mm_add_ps(r, _mm_mul_ps(w, sr));
    g = _mm_add_ps(g, _mm_mul_ps(w, sg));
    b = _mm_add_ps(b, _mm_mul_ps(w, sb));
    w = _mm_mul_ps(w, _mm_sub_ps(_mm_set1_ps(1.0f), sa));
  } else if constexpr (M == CompositeMode::Additive) {
    r = _mm_add_ps(r, sr);
    g = _mm_add_ps(g, sg);
    b = _mm_add_ps(b, sb);
    w = _mm_add_ps(w, sa);
  } else {
    r = _mm_max_ps(sr, r);  // sr > r ? sr : r, as fold<Mip>
    g = _mm_max_ps(sg, g);
    b = _mm_max_ps(sb, b);
    w = _mm_max_ps(sa, w);
  }
}
#endif

// A block's partial. The block is cut into four runs, composited side by side
// and then folded front to back: "over" is associative, and the runs are
// independent chains, about three times faster than one chain of n steps.
// The runs are lanes 0..2 of n/4 samples and lane 3 with the rest. Not
// inlined: every caller runs the same instructions, so a block's partial has
// the same bits whichever path computes it.
template <SampleFormat F, CompositeMode M>
[[gnu::noinline]] Partial blockPartial(const typename Storage<F>::T* src, int n, float* scratch) {
  const float* s = decode<F>(src, n, scratch);
  const int q = n / 4;
  Partial lane[4];
  for (auto& l : lane) l = identityPartial<M>();
#if defined(__SSE2__)
  if (q > 0) {
    const Partial id = identityPartial<M>();
    __m128 r = _mm_set1_ps(id.r), g = _mm_set1_ps(id.g), b = _mm_set1_ps(id.b), w = _mm_set1_ps(id.w);
    const float *s0 = s, *s1 = s + 4 * q, *s2 = s + 8 * q, *s3 = s + 12 * q;
    for (int i = 0; i < q; ++i) {
      __m128 x0 = _mm_loadu_ps(s0 + 4 * i), x1 = _mm_loadu_ps(s1 + 4 * i), x2 = _mm_loadu_ps(s2 + 4 * i),
             x3 = _mm_loadu_ps(s3 + 4 * i);
      _MM_TRANSPOSE4_PS(x0, x1, x2, x3);
      foldLanes<M>(r, g, b, w, x0, x1, x2, x3);
    }
    alignas(16) float lr[4], lg[4], lb[4], lw[4];
    _mm_store_ps(lr, r);
    _mm_store_ps(lg, g);
    _mm_store_ps(lb, b);
    _mm_store_ps(lw, w);
    for (int j = 0; j < 4; ++j) lane[j] = Partial{lr[j], lg[j], lb[j], lw[j]};
  }
#else
  for (int i = 0; i < q; ++i)
    for (int j = 0; j < 4; ++j) foldSample<M>(lane[j], s + 4 * (j * q + i));
#endif
  for (int k = 4 * q; k < n; ++k) foldSample<M>(lane[3], s + 4 * k);
  Partial p = lane[0];
  for (int j = 1; j < 4; ++j) fold<M>(p, lane[j].r, lane[j].g, lane[j].b, lane[j].w);
  return p;
}

// A ray's samples (RayCache::Ray::at): block b's first sample is
// sample + b * stride.
struct RayView {
  std::uint64_t sample, block;
  std::uint32_t count, stride;
};

// Walks the ray's blocks front to back, stopping before the first block at
// which "over" has reached the termination limit. With `partials`, clean
// blocks are reused and the dirty ones reached are recomputed, stored and
// cleaned; without, every block reached is computed. Returns the composite;
// `end` is the number of blocks folded, `computed` counts blocks computed.
// Not inlined, for the reason blockPartial is not.
template <SampleFormat F, CompositeMode M>
[[gnu::noinline]] Partial walkRay(const RayView& ray, const typename Storage<F>::T* samples, int blockSize, int blockShift,
                Partial* partials, std::uint8_t* dirty, float limit, std::uint32_t& end, std::uint64_t& computed,
                float* scratch) {
  Partial acc = identityPartial<M>();
  const std::uint32_t nb = (ray.count + static_cast<std::uint32_t>(blockSize) - 1) >> blockShift;
  std::uint32_t b = 0;
  for (; b < nb; ++b) {
    if constexpr (M == CompositeMode::Over) {
      if (acc.w <= limit) break;
    }
    Partial p;
    const std::uint8_t state = partials ? dirty[ray.block + b] : kBlockDirty;
    if (state == kBlockTransparent) {
      p = identityPartial<M>();
    } else if (state == kBlockDirty) {
      const std::uint32_t first = b << blockShift;
      const int n = static_cast<int>(std::min<std::uint32_t>(static_cast<std::uint32_t>(blockSize), ray.count - first));
      p = blockPartial<F, M>(samples + 4 * (ray.sample + static_cast<std::uint64_t>(b) * ray.stride), n, scratch);
      ++computed;
      if (partials) {
        partials[ray.block + b] = p;
        dirty[ray.block + b] = kBlockClean;
      }
    } else {
      p = partials[ray.block + b];
    }
    fold<M>(acc, p.r, p.g, p.b, p.w);
  }
  end = b;
  return acc;
}

// What turns a ray's partial into its pixel: additive's scale, and for MIP
// and additive (grey values, gp/ray_sampler) the window from grey level lo
// (black) over 1 / invWidth grey levels (white).
struct Finish {
  float additiveScale = 1.0f, lo = 0.0f, invWidth = 1.0f / 255.0f;
};

template <CompositeMode M>
inline void finish(const Partial& acc, const Finish& f, float* out) {
  if constexpr (M == CompositeMode::Over) {
    out[0] = acc.r;
    out[1] = acc.g;
    out[2] = acc.b;
    out[3] = 1.0f - acc.w;
  } else {
    // MIP: the largest grey value; additive: the sum of grey value times step.
    const float grey = M == CompositeMode::Mip ? acc.r * 255.0f : acc.w * 255.0f * f.additiveScale;
    const float v = std::min(1.0f, std::max(0.0f, (grey - f.lo) * f.invWidth));
    // White of coverage v, premultiplied: v over black. A ray with no
    // samples gives 0 like a cleared pixel, the window's black being >= 0.
    out[0] = out[1] = out[2] = out[3] = v;
  }
}

}  // namespace pp5::pp::composite
