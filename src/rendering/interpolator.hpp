#pragma once
// Trilinear interpolation of the shade buffer at the sample lattice's points,
// four consecutive samples of a ray at a time: which cell each sample reads
// (the stencil rule, rendering/stencil.hpp) and its premultiplied RGBA there. Used
// by the sampler's loops; header-only so they inline it.
#include <algorithm>
#include <cstdint>
#include <cstring>

#include "core/error.hpp"
#include "core/sample_lattice.hpp"
#include "rendering/empty_space.hpp"
#include "rendering/shade_buffer.hpp"
#include "core/simd.hpp"

namespace pp5::gp {

// Four consecutive samples of a ray, located: the cell each one reads (its
// lowest voxel, clamped to the grid's last cell) and its fractions in it.
struct Cells4 {
  alignas(16) std::int32_t i[3][4];
  alignas(16) float f[3][4];
};

class Interpolator {
public:
  using F4 = simd::F4;
  using I4 = simd::I4;
  explicit Interpolator(const ShadeBuffer& shade)
      : v_(shade.data()), sy_(shade.grid().dims.x), sz_(shade.grid().dims.x * shade.grid().dims.y) {
    const Index3& d = shade.grid().dims;
    PP5_CHECK_GE(d.x, 2);
    PP5_CHECK_GE(d.y, 2);
    PP5_CHECK_GE(d.z, 2);
    for (int a = 0; a < 3; ++a) cmax_[a] = static_cast<float>(d[a] - 2);
  }

  // Samples k .. k + 3. Positions are VoxelRay::at's, lane by lane; a point a
  // hair outside the sampling box (float rounding) reads its nearest cell at
  // fraction 0 or 1.
  void locate4(const VoxelRay& r, std::uint32_t k, Cells4& c) const {
    const auto k0 = static_cast<std::int32_t>(k);
    const F4 kf = __builtin_convertvector((I4{k0, k0 + 1, k0 + 2, k0 + 3}), F4);
    const F4 zero = simd::splat(0.0f), one = simd::splat(1.0f);
    for (int a = 0; a < 3; ++a) {
      const F4 p = simd::splat(r.base[a]) + kf * simd::splat(r.delta[a]);
      const I4 i = __builtin_convertvector(simd::vmin(simd::vmax(p, zero), simd::splat(cmax_[a])), I4);
      const F4 f = simd::vmin(simd::vmax(p - __builtin_convertvector(i, F4), zero), one);
      std::memcpy(c.i[a], &i, sizeof(I4));
      std::memcpy(c.f[a], &f, sizeof(F4));
    }
  }

  // The cell of sample k alone: lane 0 of locate4, by the same operations.
  std::int32_t cellAxis(const VoxelRay& r, std::uint32_t k, int a) const {
    const float p = r.base[a] + static_cast<float>(k) * r.delta[a];
    return static_cast<std::int32_t>(std::min(std::max(p, 0.0f), cmax_[a]));
  }

  const ShadeVoxel* cell(const Cells4& c, int lane) const {
    return v_ + (static_cast<std::int64_t>(c.i[2][lane]) * sz_ + static_cast<std::int64_t>(c.i[1][lane]) * sy_ +
                 c.i[0][lane]);
  }

  // The 8 voxels of the four lanes' cells; with `cellBits`
  // (EmptySpaceMap::cellBits), only of the cells whose bit is set.
  void prefetch(const Cells4& c, const std::uint64_t* cellBits = nullptr) const {
#if defined(__SSE2__)
    for (int l = 0; l < 4; ++l) {
      const std::int64_t i = index(c, l);
      if (cellBits && !EmptySpaceMap::bitSet(cellBits, i)) continue;
      const char* q = reinterpret_cast<const char*>(v_ + i);
      _mm_prefetch(q, _MM_HINT_T0);
      _mm_prefetch(q + 4 * sy_, _MM_HINT_T0);
      _mm_prefetch(q + 4 * sz_, _MM_HINT_T0);
      _mm_prefetch(q + 4 * (sz_ + sy_), _MM_HINT_T0);
    }
#else
    (void)c;
    (void)cellBits;
#endif
  }

  // The 8 voxels of a cell as floats (0..255): x, x+1 at (y, z), (y+1, z),
  // (y, z+1), (y+1, z+1). Consecutive samples often share a cell.
  struct Voxels {
#if defined(__SSE2__)
    __m128 v[8];
#else
    float v[8][4];
#endif
  };

  std::int64_t index(const Cells4& c, int lane) const {
    return static_cast<std::int64_t>(c.i[2][lane]) * sz_ + static_cast<std::int64_t>(c.i[1][lane]) * sy_ + c.i[0][lane];
  }

  void load(std::int64_t index, Voxels& out) const {
    const ShadeVoxel* q = v_ + index;
    const ShadeVoxel* row[4] = {q, q + sy_, q + sz_, q + sz_ + sy_};
#if defined(__SSE2__)
    const __m128i zero = _mm_setzero_si128();
    for (int r = 0; r < 4; ++r) {
      // One 8-byte load holds a voxel and its +x neighbour.
      const __m128i w = _mm_unpacklo_epi8(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(row[r])), zero);
      out.v[2 * r] = _mm_cvtepi32_ps(_mm_unpacklo_epi16(w, zero));
      out.v[2 * r + 1] = _mm_cvtepi32_ps(_mm_unpackhi_epi16(w, zero));
    }
#else
    for (int r = 0; r < 4; ++r)
      for (int x = 0; x < 2; ++x) {
        const ShadeVoxel& s = row[r][x];
        out.v[2 * r + x][0] = s.r;
        out.v[2 * r + x][1] = s.g;
        out.v[2 * r + x][2] = s.b;
        out.v[2 * r + x][3] = s.a;
      }
#endif
  }

  // Premultiplied r, g, b, a in 0..255 of one lane: lerps along x, then y,
  // then z.
  static void blend(const Voxels& v, const Cells4& c, int lane, float* rgba) {
    const float fx0 = c.f[0][lane], fy0 = c.f[1][lane], fz0 = c.f[2][lane];
#if defined(__SSE2__)
    auto lerp = [](__m128 a, __m128 b, __m128 t) { return _mm_add_ps(a, _mm_mul_ps(_mm_sub_ps(b, a), t)); };
    const __m128 fx = _mm_set1_ps(fx0), fy = _mm_set1_ps(fy0), fz = _mm_set1_ps(fz0);
    const __m128 y0 = lerp(lerp(v.v[0], v.v[1], fx), lerp(v.v[2], v.v[3], fx), fy);
    const __m128 y1 = lerp(lerp(v.v[4], v.v[5], fx), lerp(v.v[6], v.v[7], fx), fy);
    _mm_storeu_ps(rgba, lerp(y0, y1, fz));
#else
    auto lerp = [](float a, float b, float t) { return a + (b - a) * t; };
    for (int k = 0; k < 4; ++k) {
      const float y0 = lerp(lerp(v.v[0][k], v.v[1][k], fx0), lerp(v.v[2][k], v.v[3][k], fx0), fy0);
      const float y1 = lerp(lerp(v.v[4][k], v.v[5][k], fx0), lerp(v.v[6][k], v.v[7][k], fx0), fy0);
      rgba[k] = lerp(y0, y1, fz0);
    }
#endif
  }

  // Lane `lane`'s sample; the cell's voxels are loaded only when the lane
  // before read another cell (`loaded`: the index of the cell in `vox`).
  void blendLane(const Cells4& c, int lane, std::int64_t& loaded, Voxels& vox, float* rgba) const {
    blendAt(c, lane, index(c, lane), loaded, vox, rgba);
  }
  // The same with the lane's cell index, index(c, lane), given.
  void blendAt(const Cells4& c, int lane, std::int64_t idx, std::int64_t& loaded, Voxels& vox, float* rgba) const {
    if (idx != loaded) {
      load(idx, vox);
      loaded = idx;
    }
    blend(vox, c, lane, rgba);
  }

  void at(const Cells4& c, int lane, float* rgba) const {
    Voxels v;
    load(index(c, lane), v);
    blend(v, c, lane, rgba);
  }

private:
  const ShadeVoxel* v_;
  std::int64_t sy_, sz_;
  float cmax_[3];
};

}  // namespace pp5::gp
