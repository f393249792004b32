#include "gp/ray_sampler.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <tuple>

#include <omp.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.hpp"

namespace pp5::gp {

// ---------------------------------------------------------------------------
// Opacity correction, four samples at a time

namespace {

// GCC vector extensions: the same IEEE operations whatever the instruction
// set (SSE2 here), so the bits do not depend on it; and one lane computed
// alone (correctOpacity, sampleAt) gives the bits of the same lane in a batch.
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

inline bool anyPositive(F4 a) {
#if defined(__SSE2__)
  return _mm_movemask_ps(_mm_cmpgt_ps(reinterpret_cast<__m128>(a), _mm_setzero_ps())) != 0;
#else
  return a[0] > 0.0f || a[1] > 0.0f || a[2] > 0.0f || a[3] > 0.0f;
#endif
}

inline F4 correctLanes(F4 a, float e) {
  if (e == 1.0f) return select(a >= splat(1.0f), splat(1.0f), select(a > splat(0.0f), a, splat(0.0f)));
  return correct4(a, e);
}

}  // namespace

float correctOpacity(float a, float e) { return correctLanes(F4{a, 0.0f, 0.0f, 0.0f}, e)[0]; }

// ---------------------------------------------------------------------------
// Trilinear interpolation of the shade buffer

namespace {

// Four consecutive samples of a ray, located: the cell each one reads (its
// lowest voxel, clamped to the grid's last cell) and its fractions in it.
struct Cells4 {
  alignas(16) std::int32_t i[3][4];
  alignas(16) float f[3][4];
};

class Interpolator {
public:
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
    const F4 zero = splat(0.0f), one = splat(1.0f);
    for (int a = 0; a < 3; ++a) {
      const F4 p = splat(r.base[a]) + kf * splat(r.delta[a]);
      const I4 i = __builtin_convertvector(vmin(vmax(p, zero), splat(cmax_[a])), I4);
      const F4 f = vmin(vmax(p - __builtin_convertvector(i, F4), zero), one);
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

  void prefetch(const Cells4& c) const {
#if defined(__SSE2__)
    for (int l = 0; l < 4; ++l) {
      const char* q = reinterpret_cast<const char*>(cell(c, l));
      _mm_prefetch(q, _MM_HINT_T0);
      _mm_prefetch(q + 4 * sy_, _MM_HINT_T0);
      _mm_prefetch(q + 4 * sz_, _MM_HINT_T0);
      _mm_prefetch(q + 4 * (sz_ + sy_), _MM_HINT_T0);
    }
#else
    (void)c;
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
    const std::int64_t idx = index(c, lane);
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

void checkSameGrid(const Grid& a, const Grid& b) {
  PP5_CHECK_EQ(a.dims.x, b.dims.x);
  PP5_CHECK_EQ(a.dims.y, b.dims.y);
  PP5_CHECK_EQ(a.dims.z, b.dims.z);
  PP5_CHECK(a.origin == b.origin && a.spacing == b.spacing);
}

int threadCount(int requested) { return requested > 0 ? requested : std::max(1, omp_get_max_threads()); }

// One thread's output: a batch that goes to the sink when full or when the
// tile ends.
class Batcher {
public:
  Batcher(SampleSink& sink, int thread, std::size_t capacity)
      : sink_(sink), thread_(thread), cap_(capacity), buf_(capacity) {}
  void startTile(std::uint32_t tile) { tile_ = tile; }
  // Room for up to `want` samples (at least one), written by the caller.
  RaySample* append(std::size_t want, std::size_t& got) {
    if (used_ == cap_) flush();
    got = std::min(want, cap_ - used_);
    RaySample* p = buf_.data() + used_;
    used_ += got;
    return p;
  }
  void flush() {
    if (used_ == 0) return;
    sink_.consume(thread_, tile_, std::span<const RaySample>(buf_.data(), used_));
    used_ = 0;
  }

private:
  SampleSink& sink_;
  int thread_;
  std::size_t cap_;
  std::uint32_t tile_ = 0;
  std::vector<RaySample> buf_;
  std::size_t used_ = 0;
};

// One ray's interpolated samples, waiting for their opacity correction, which
// runs over four samples at a time (it is most of a sample's arithmetic).
class RayStage {
public:
  explicit RayStage(int maxSamples, float exponent) : e_(exponent) {
    const std::size_t cap = static_cast<std::size_t>(maxSamples) + 4;
    rgba_.resize(4 * cap);
    a_.resize(cap);
    k_.resize(cap);
    ap_.resize(cap);
    scale_.resize(cap);
  }
  // Where the next sample's interpolated r, g, b, a go.
  float* slot() { return rgba_.data() + 4 * n_; }
  void commit(std::uint32_t k) {
    a_[n_] = rgba_[4 * n_ + 3];
    k_[n_++] = k;
  }
  void emit(std::uint32_t pixel, Batcher& out) {
    if (n_ == 0) return;
    for (std::size_t i = n_; i % 4 != 0; ++i) a_[i] = 0.0f;
    for (std::size_t i = 0; i < n_; i += 4) {
      F4 a255;
      std::memcpy(&a255, a_.data() + i, sizeof(F4));
      F4 ap = splat(0.0f), scale = splat(0.0f);
      // Transparent runs (sampleRegion rewrites them too) need no arithmetic.
      if (anyPositive(a255)) {
        ap = correctLanes(a255 * splat(1.0f / 255.0f), e_);
        scale = select(a255 > splat(0.0f), ap / a255, splat(0.0f));
      }
      std::memcpy(ap_.data() + i, &ap, sizeof(F4));
      std::memcpy(scale_.data() + i, &scale, sizeof(F4));
    }
    for (std::size_t i = 0; i < n_;) {
      std::size_t m;
      RaySample* dst = out.append(n_ - i, m);
      for (std::size_t j = 0; j < m; ++j, ++i) {
        const float* c = rgba_.data() + 4 * i;
        dst[j] = RaySample{pixel, k_[i], c[0] * scale_[i], c[1] * scale_[i], c[2] * scale_[i], ap_[i]};
      }
    }
    n_ = 0;
  }

private:
  float e_;
  std::size_t n_ = 0;
  std::vector<float> rgba_, a_, ap_, scale_;
  std::vector<std::uint32_t> k_;
};

// Margin (voxels) by which an empty cube is shrunk before a ray jumps across
// it: a skipped sample is then inside the cube by far more than the float
// error of its position.
constexpr double kSkipMarginVoxels = 1.0 / 64.0;

// Jumps along a ray over a cube of empty bricks: the cube of bricks within
// d - 1 of brick b is empty, so the next sample worth looking at is where
// the ray leaves it, per axis at k = (b + d) * slope + offset (b - d + 1
// going down), the cube shrunk by the margin.
struct BrickJump {
  double inv[3], slope[3], offset[3];
  int side[3];
  explicit BrickJump(const VoxelRay& vr) {
    for (int a = 0; a < 3; ++a) {
      const double dl = vr.delta[a];
      inv[a] = dl != 0.0 ? 1.0 / dl : 0.0;
      side[a] = inv[a] > 0.0 ? 1 : (inv[a] < 0.0 ? -1 : 0);
      slope[a] = EmptySpaceMap::kBrickCells * inv[a];
      offset[a] = (-static_cast<double>(vr.base[a]) - side[a] * kSkipMarginVoxels) * inv[a];
    }
  }
  // The sample after the cube (at least k + 1), or kEnd + 1 when the cube reaches past kEnd.
  template <class K>
  K next(const int (&b)[3], int d, K k, K kEnd) const {
    double kExit = std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a)
      if (side[a] != 0) kExit = std::min(kExit, (side[a] > 0 ? b[a] + d : b[a] - d + 1) * slope[a] + offset[a]);
    return kExit >= static_cast<double>(kEnd) ? kEnd + 1 : std::max(k + 1, static_cast<K>(std::max(kExit, 0.0)) + 1);
  }
};

float exponentOf(const SampleLattice& lattice, const RenderSettings& settings) {
  PP5_CHECK_GT(settings.opacityUnitMm, 0.0);
  return static_cast<float>(lattice.step() / settings.opacityUnitMm);
}

}  // namespace

// ---------------------------------------------------------------------------
// Grow rule

std::vector<WorldBox> stencilBoxes(const Grid& g, std::span<const Box3> changed, int extraVoxels) {
  PP5_CHECK_GE(extraVoxels, 0);
  std::vector<WorldBox> out;
  out.reserve(changed.size());
  const Vec3 top = Vec3(g.dims - Index3(1));
  for (const Box3& b : changed) {
    const Box3 v = b.grown(extraVoxels);
    if (v.empty()) continue;
    // Cells v.lo - 1 .. v.hi - 1 read a voxel of v: points [v.lo - 1, v.hi].
    const Vec3 lo = glm::max(Vec3(v.lo - Index3(1)), Vec3(0.0));
    const Vec3 hi = glm::min(Vec3(v.hi), top);
    if (hi.x < lo.x || hi.y < lo.y || hi.z < lo.z) continue;
    out.push_back({g.voxelToWorld(lo - Vec3(kStencilSlackVoxels)), g.voxelToWorld(hi + Vec3(kStencilSlackVoxels))});
  }
  return out;
}

std::vector<WorldBox> stencilBoxes(const DirtyRegion& changed, int extraVoxels) {
  const Index3 bd = changed.brickDims();
  const std::int64_t B = changed.brickSize();
  // Runs along x, then runs of equal x-extent stacked along y, then rectangles
  // of equal extent stacked along z: brick ids are sorted z, y, x, so each
  // merge sees its candidates in order.
  struct Rect {
    std::int64_t x0, x1, y0, y1, z0, z1;  // inclusive brick coordinates
  };
  std::vector<Rect> runs;
  for (const auto id : changed.bricks()) {
    const std::int64_t x = id % bd.x, y = (id / bd.x) % bd.y, z = id / (bd.x * bd.y);
    if (!runs.empty() && runs.back().y0 == y && runs.back().z0 == z && runs.back().x1 + 1 == x) {
      runs.back().x1 = x;
    } else {
      runs.push_back({x, x, y, y, z, z});
    }
  }
  std::vector<Rect> rects;
  std::map<std::tuple<std::int64_t, std::int64_t, std::int64_t>, std::size_t> openY;
  for (const Rect& r : runs) {
    const auto key = std::make_tuple(r.z0, r.x0, r.x1);
    auto it = openY.find(key);
    if (it != openY.end() && rects[it->second].y1 + 1 == r.y0) {
      rects[it->second].y1 = r.y0;
    } else {
      openY[key] = rects.size();
      rects.push_back(r);
    }
  }
  std::vector<Rect> boxes;
  std::map<std::tuple<std::int64_t, std::int64_t, std::int64_t, std::int64_t>, std::size_t> openZ;
  for (const Rect& r : rects) {
    const auto key = std::make_tuple(r.x0, r.x1, r.y0, r.y1);
    auto it = openZ.find(key);
    if (it != openZ.end() && boxes[it->second].z1 + 1 == r.z0) {
      boxes[it->second].z1 = r.z0;
    } else {
      openZ[key] = boxes.size();
      boxes.push_back(r);
    }
  }
  std::vector<Box3> voxels;
  voxels.reserve(boxes.size());
  const Box3 all{Index3(0), changed.grid().dims};
  for (const Rect& r : boxes)
    voxels.push_back(Box3{Index3(r.x0, r.y0, r.z0) * B, Index3(r.x1 + 1, r.y1 + 1, r.z1 + 1) * B}.intersect(all));
  return stencilBoxes(changed.grid(), voxels, extraVoxels);
}

// ---------------------------------------------------------------------------
// Empty space

EmptySpaceMap::EmptySpaceMap(const ShadeBuffer& shade, int threads) : grid_(shade.grid()) {
  const Index3& d = grid_.dims;
  PP5_CHECK_GE(d.x, 2);
  PP5_CHECK_GE(d.y, 2);
  PP5_CHECK_GE(d.z, 2);
  bdims_ = (cellDims() + Index3(kBrickCells - 1)) / Index3(kBrickCells);
  const std::size_t n = static_cast<std::size_t>(bdims_.x * bdims_.y * bdims_.z);
  occupied_.assign(n, 0);
  dist_.assign(n, 0);
  const std::int64_t slices = bdims_.z * bdims_.y;
#pragma omp parallel for num_threads(threadCount(threads)) schedule(dynamic, 1)
  for (std::int64_t s = 0; s < slices; ++s)
    for (std::int64_t bi = 0; bi < bdims_.x; ++bi) scanBrick(shade, bi, s % bdims_.y, s / bdims_.y);
  computeDistances();
}

void EmptySpaceMap::scanBrick(const ShadeBuffer& shade, std::int64_t bi, std::int64_t bj, std::int64_t bk) {
  // The brick's cells read voxels [lo, lo + kBrickCells] inclusive.
  const Index3 lo = Index3(bi, bj, bk) * Index3(kBrickCells);
  const Index3 hi = glm::min(lo + Index3(kBrickCells + 1), grid_.dims);
  occupied_[static_cast<std::size_t>((bk * bdims_.y + bj) * bdims_.x + bi)] = anyVisible(shade, {lo, hi}) ? 1 : 0;
}

bool EmptySpaceMap::anyVisible(const ShadeBuffer& shade, const Box3& b) const {
  // OR whole voxels as 32-bit words and keep alpha, the high byte (r, g, b,
  // a in memory, little-endian); a full brick's rows (9 voxels) with a fixed
  // count the compiler unrolls.
  static_assert(std::endian::native == std::endian::little);
  const ShadeVoxel* v = shade.data();
  const std::int64_t n = b.hi.x - b.lo.x;
  if (n <= 0) return false;
  auto orRow = [](const ShadeVoxel* row, std::int64_t count) {
    std::uint32_t acc = 0;
    for (std::int64_t x = 0; x < count; ++x) {
      std::uint32_t w;
      std::memcpy(&w, row + x, sizeof w);
      acc |= w;
    }
    return acc;
  };
  std::uint32_t any = 0;
  for (std::int64_t z = b.lo.z; z < b.hi.z && !any; ++z)
    for (std::int64_t y = b.lo.y; y < b.hi.y; ++y) {
      const ShadeVoxel* row = v + grid_.linear(b.lo.x, y, z);
      any |= (n == kBrickCells + 1 ? orRow(row, kBrickCells + 1) : orRow(row, n)) >> 24;
    }
  return any != 0;
}

void EmptySpaceMap::update(const ShadeBuffer& shade, std::span<const Box3> changed) {
  checkSameGrid(shade.grid(), grid_);
  std::vector<std::uint8_t> seen(occupied_.size(), 0);
  std::vector<Box3> inGrid;
  for (const Box3& b0 : changed) {
    const Box3 b = b0.intersect({Index3(0), grid_.dims});
    if (!b.empty()) inGrid.push_back(b);
  }
  bool any = false;
  for (const Box3& b : inGrid) {
    // Voxel v is read by cells v - 1 and v.
    const Index3 clo = glm::max(b.lo - Index3(1), Index3(0)) / Index3(kBrickCells);
    const Index3 chi = glm::min((b.hi - Index3(1)) / Index3(kBrickCells), bdims_ - Index3(1));
    for (std::int64_t k = clo.z; k <= chi.z; ++k)
      for (std::int64_t j = clo.y; j <= chi.y; ++j)
        for (std::int64_t i = clo.x; i <= chi.x; ++i) {
          const auto id = static_cast<std::size_t>((k * bdims_.y + j) * bdims_.x + i);
          if (seen[id]) continue;
          seen[id] = 1;
          any = true;
          if (occupied_[id]) {
            scanBrick(shade, i, j, k);
            continue;
          }
          // Empty before: every voxel it reads was transparent, and only the
          // changed boxes were re-shaded, so only their part can be visible now.
          const Index3 lo = Index3(i, j, k) * Index3(kBrickCells);
          const Box3 reads{lo, glm::min(lo + Index3(kBrickCells + 1), grid_.dims)};
          bool visible = false;
          for (const Box3& c : inGrid) {
            visible = anyVisible(shade, reads.intersect(c));
            if (visible) break;
          }
          occupied_[id] = visible ? 1 : 0;
        }
  }
  if (any) computeDistances();
}

void EmptySpaceMap::computeDistances() {
  // Two raster passes with the full 26-neighbour mask give the exact
  // chessboard distance. The map is padded by one brick of "infinity" on
  // every side, so no neighbour needs a bounds check. In each pass a row
  // first takes the 12 neighbours of the rows already done (independent
  // along x, so vectorised), then the one before it in the same row, in order.
  const std::int64_t X = bdims_.x, Y = bdims_.y, Z = bdims_.z;
  const std::int64_t PX = X + 2, PY = Y + 2, PZ = Z + 2;
  constexpr std::uint16_t kInf = 0x7fff;  // + 1 cannot overflow, and stays above every distance
  std::vector<std::uint16_t> pad(static_cast<std::size_t>(PX * PY * PZ), kInf);
  auto at = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
    return static_cast<std::size_t>((z * PY + y) * PX + x);
  };
  for (std::int64_t z = 0; z < Z; ++z)
    for (std::int64_t y = 0; y < Y; ++y)
      for (std::int64_t x = 0; x < X; ++x)
        if (occupied_[static_cast<std::size_t>((z * Y + y) * X + x)]) pad[at(x + 1, y + 1, z + 1)] = 0;
  std::vector<std::uint16_t> t(static_cast<std::size_t>(PX));
  auto pass = [&](int sign) {
    // The 12 earlier neighbours' offsets: the previous row of this plane and
    // the previous plane's 3x3 rows, in this pass's direction.
    std::int64_t off[12];
    int n = 0;
    for (int dx = -1; dx <= 1; ++dx) off[n++] = sign * (-PX + dx);
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) off[n++] = sign * (-PX * PY + dy * PX + dx);
    for (std::int64_t zz = 0; zz < Z; ++zz)
      for (std::int64_t yy = 0; yy < Y; ++yy) {
        const std::int64_t z = sign > 0 ? zz + 1 : Z - zz, y = sign > 0 ? yy + 1 : Y - yy;
        std::uint16_t* row = pad.data() + at(0, y, z);
        for (std::int64_t x = 1; x <= X; ++x) {
          std::uint16_t m = row[x + off[0]];
          for (int q = 1; q < 12; ++q) m = std::min(m, row[x + off[q]]);
          t[static_cast<std::size_t>(x)] = std::min<std::uint16_t>(row[x], static_cast<std::uint16_t>(m + 1));
        }
        if (sign > 0)
          for (std::int64_t x = 1; x <= X; ++x)
            row[x] = std::min<std::uint16_t>(t[static_cast<std::size_t>(x)], static_cast<std::uint16_t>(row[x - 1] + 1));
        else
          for (std::int64_t x = X; x >= 1; --x)
            row[x] = std::min<std::uint16_t>(t[static_cast<std::size_t>(x)], static_cast<std::uint16_t>(row[x + 1] + 1));
      }
  };
  pass(1);
  pass(-1);
  auto idx = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
    return static_cast<std::size_t>((z * Y + y) * X + x);
  };
  for (std::int64_t z = 0; z < Z; ++z)
    for (std::int64_t y = 0; y < Y; ++y)
      for (std::int64_t x = 0; x < X; ++x)
        dist_[idx(x, y, z)] = static_cast<std::uint8_t>(std::min<std::uint16_t>(pad[at(x + 1, y + 1, z + 1)], 255));
  Box3 b{bdims_, Index3(0)};
  for (std::int64_t z = 0; z < Z; ++z)
    for (std::int64_t y = 0; y < Y; ++y)
      for (std::int64_t x = 0; x < X; ++x)
        if (occupied_[idx(x, y, z)]) {
          b.lo = glm::min(b.lo, Index3(x, y, z));
          b.hi = glm::max(b.hi, Index3(x, y, z) + Index3(1));
        }
  occupiedCells_ = b.empty() ? Box3{} : Box3{b.lo * Index3(kBrickCells), glm::min(b.hi * Index3(kBrickCells), cellDims())};
}

std::vector<Box3> EmptySpaceMap::visibleVoxelBoxes(const Box3& within) const {
  std::vector<Box3> out;
  const Box3 clip = within.intersect({Index3(0), grid_.dims});
  if (clip.empty() || occupied_.empty()) return out;
  constexpr std::int64_t B = kBrickCells;
  // Voxel brick v holds voxels [B v, B v + B); cell brick c reads voxels
  // [B c, B c + B] (scanBrick), so v is read by cell bricks v - 1 and v on
  // each axis.
  auto occupied = [&](std::int64_t i, std::int64_t j, std::int64_t k) {
    if (i < 0 || j < 0 || k < 0 || i >= bdims_.x || j >= bdims_.y || k >= bdims_.z) return false;
    return occupied_[static_cast<std::size_t>((k * bdims_.y + j) * bdims_.x + i)] != 0;
  };
  auto needed = [&](std::int64_t i, std::int64_t j, std::int64_t k) {
    for (int dz = -1; dz <= 0; ++dz)
      for (int dy = -1; dy <= 0; ++dy)
        for (int dx = -1; dx <= 0; ++dx)
          if (occupied(i + dx, j + dy, k + dz)) return true;
    return false;
  };
  const Index3 lo = clip.lo / Index3(B), hi = (clip.hi + Index3(B - 1)) / Index3(B);
  for (std::int64_t k = lo.z; k < hi.z; ++k)
    for (std::int64_t j = lo.y; j < hi.y; ++j)
      for (std::int64_t i = lo.x; i < hi.x;) {
        if (!needed(i, j, k)) {
          ++i;
          continue;
        }
        std::int64_t e = i + 1;
        while (e < hi.x && needed(e, j, k)) ++e;
        const Box3 run = Box3{Index3(i, j, k) * Index3(B), Index3(e, j + 1, k + 1) * Index3(B)}.intersect(clip);
        if (!run.empty()) out.push_back(run);
        i = e;
      }
  return out;
}

double EmptySpaceMap::emptyFraction() const {
  if (occupied_.empty()) return 0.0;
  std::size_t n = 0;
  for (const auto o : occupied_) n += o == 0;
  return static_cast<double>(n) / static_cast<double>(occupied_.size());
}

// ---------------------------------------------------------------------------
// Sinks

void SampleCollector::consume(int, std::uint32_t tile, std::span<const RaySample> samples) {
  std::lock_guard<std::mutex> lock(m_);
  if (tile >= tiles_.size()) tiles_.resize(tile + 1);
  tiles_[tile].insert(tiles_[tile].end(), samples.begin(), samples.end());
}

std::vector<RaySample> SampleCollector::samples() const {
  std::lock_guard<std::mutex> lock(m_);
  std::vector<RaySample> out;
  std::size_t n = 0;
  for (const auto& t : tiles_) n += t.size();
  out.reserve(n);
  for (const auto& t : tiles_) out.insert(out.end(), t.begin(), t.end());
  return out;
}

std::size_t SampleCollector::size() const {
  std::lock_guard<std::mutex> lock(m_);
  std::size_t n = 0;
  for (const auto& t : tiles_) n += t.size();
  return n;
}

void SampleCollector::clear() {
  std::lock_guard<std::mutex> lock(m_);
  tiles_.clear();
}

// ---------------------------------------------------------------------------
// Sampling

namespace {

struct TileGrid {
  int size, nx, ny;
  TileGrid(int w, int h, int t) : size(t), nx((w + t - 1) / t), ny((h + t - 1) / t) { PP5_CHECK_GT(t, 0); }
  std::uint32_t count() const { return static_cast<std::uint32_t>(nx) * static_cast<std::uint32_t>(ny); }
};

constexpr int kBrickShift = 3;

// The empty-space brick (EmptySpaceMap::kBrickCells cells a side) of lane
// `lane`'s cell, in a map of `bd` bricks.
inline std::size_t brickOf(const Cells4& c, int lane, const Index3& bd) {
  return static_cast<std::size_t>((static_cast<std::int64_t>(c.i[2][lane] >> kBrickShift) * bd.y +
                                   (c.i[1][lane] >> kBrickShift)) *
                                      bd.x +
                                  (c.i[0][lane] >> kBrickShift));
}
static_assert(EmptySpaceMap::kBrickCells == 1 << kBrickShift);

// The work tiles to sample: all of them (`list` empty, `all` true), or the
// ones options.workTiles selects, in ascending order.
struct TileSelection {
  bool all = true;
  std::vector<std::uint32_t> list;
  TileSelection(const TileGrid& tiles, const std::vector<std::uint8_t>& mask) {
    if (mask.empty()) return;
    PP5_CHECK_EQ(mask.size(), static_cast<std::size_t>(tiles.count()));
    all = false;
    for (std::uint32_t t = 0; t < tiles.count(); ++t)
      if (mask[t] != 0) list.push_back(t);
  }
};

// The smallest k in [a, b] with pred(k) false (b + 1 when there is none), for
// a pred that is true up to some k and false from there on. It gallops up
// from a and then bisects, so a boundary near a costs a call or two.
template <class P>
std::int64_t firstFalse(const P& pred, std::int64_t a, std::int64_t b) {
  if (a > b || !pred(a)) return a;
  std::int64_t lo = a, hi = b + 1;  // pred(lo) is true; hi is false or past b
  for (std::int64_t step = 1; lo + step <= b; step *= 2) {
    if (!pred(lo + step)) {
      hi = lo + step;
      break;
    }
    lo += step;
  }
  while (hi - lo > 1) {
    const std::int64_t m = lo + (hi - lo) / 2;
    (pred(m) ? lo : hi) = m;
  }
  return hi;
}

// SamplerOptions::ownedCells for one call: a conservative clip of a ray to
// the box, and the exact run of the ray's samples whose cell is in it.
class OwnedCells {
public:
  OwnedCells(const Box3& cells, const Index3& cellDims)
      : box_{glm::max(cells.lo, Index3(0)), glm::min(cells.hi, cellDims)} {
    const double inf = std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a) {
      // A cell on a face of the grid also takes the points beyond the face
      // (the cell index is clamped), so the bound goes to infinity there.
      lo_[a] = box_.lo[a] <= 0 ? -inf : static_cast<double>(box_.lo[a]) - kSkipMarginVoxels;
      hi_[a] = box_.hi[a] >= cellDims[a] ? inf : static_cast<double>(box_.hi[a]) + kSkipMarginVoxels;
    }
  }
  const Box3& box() const { return box_; }
  bool empty() const { return box_.empty(); }
  // The points that can have their cell in the box: [lo, hi] in voxel
  // coordinates, per axis.
  double lo(int a) const { return lo_[a]; }
  double hi(int a) const { return hi_[a]; }

  // Narrows [k0, k1], a range of samples of `vr` that holds all of its owned
  // samples in it, to exactly the owned ones; false when there are none. Along
  // the ray each axis' cell is monotone in k (VoxelRay::at rounds
  // monotonically), so the owned samples are one run: the first sample past
  // the box's near faces, up to the last one before its far faces.
  bool exact(const Interpolator& interp, const VoxelRay& vr, std::int64_t& k0, std::int64_t& k1) const {
    if (k0 > k1) return false;
    int side[3];
    for (int a = 0; a < 3; ++a) {
      side[a] = vr.delta[a] > 0.0f ? 1 : (vr.delta[a] < 0.0f ? -1 : 0);
      if (side[a] == 0) {  // one cell along this axis for the whole ray
        const std::int64_t c = interp.cellAxis(vr, static_cast<std::uint32_t>(k0), a);
        if (c < box_.lo[a] || c >= box_.hi[a]) return false;
      }
    }
    auto cell = [&](std::int64_t k, int a) -> std::int64_t {
      return interp.cellAxis(vr, static_cast<std::uint32_t>(k), a);
    };
    // Not yet in the box along some axis / already past it along some axis.
    auto before = [&](std::int64_t k) {
      for (int a = 0; a < 3; ++a)
        if (side[a] > 0 ? cell(k, a) < box_.lo[a] : (side[a] < 0 && cell(k, a) >= box_.hi[a])) return true;
      return false;
    };
    auto past = [&](std::int64_t k) {
      for (int a = 0; a < 3; ++a)
        if (side[a] > 0 ? cell(k, a) >= box_.hi[a] : (side[a] < 0 && cell(k, a) < box_.lo[a])) return true;
      return false;
    };
    const std::int64_t first = firstFalse(before, k0, k1);
    if (first > k1) return false;
    const std::int64_t last = k1 - firstFalse([&](std::int64_t j) { return past(k1 - j); }, 0, k1 - first);
    if (last < first) return false;
    k0 = first;
    k1 = last;
    return true;
  }

private:
  Box3 box_;
  double lo_[3], hi_[3];
};

// The visible samples of a ray's samples k .. kEnd into the stage: jumps
// over empty cubes, and samples four at a time in visible bricks. Inlined
// into each caller, so each gets the code for its own range.
[[gnu::always_inline]] inline void walkVisible(const Interpolator& interp, const VoxelRay& vr, const BrickJump& jump,
                                               const std::uint8_t* dist, const Index3& bd, std::uint32_t k,
                                               const std::uint32_t kEnd, RayStage& stage) {
  Cells4 c, next;
  Interpolator::Voxels vox{};
  std::int64_t loaded = -1;
  while (k <= kEnd) {
    const int b[3] = {interp.cellAxis(vr, k, 0) >> kBrickShift, interp.cellAxis(vr, k, 1) >> kBrickShift,
                      interp.cellAxis(vr, k, 2) >> kBrickShift};
    const int d = dist[(static_cast<std::int64_t>(b[2]) * bd.y + b[1]) * bd.x + b[0]];
    if (d > 0) {  // in an empty cube: no sample of a visible brick is skipped
      k = jump.next(b, d, k, kEnd);
      continue;
    }
    // A visible brick: sample four at a time until a group starts in an
    // empty brick. The next group is located one ahead, so that its voxels
    // can be fetched while this one is interpolated.
    interp.locate4(vr, k, c);
    for (std::uint32_t g = k;; g += 4) {
      if (g + 4 <= kEnd) {
        interp.locate4(vr, g + 4, next);
        interp.prefetch(next);
      }
      const int lanes = static_cast<int>(std::min<std::uint32_t>(4, kEnd - g + 1));
      for (int l = 0; l < lanes; ++l) {
        float* rgba = stage.slot();
        interp.blendLane(c, l, loaded, vox, rgba);
        if (rgba[3] > 0.0f) stage.commit(g + static_cast<std::uint32_t>(l));
      }
      if (g + 4 > kEnd) {
        k = g + 4;
        break;
      }
      std::swap(c, next);
      if (dist[brickOf(c, 0, bd)] != 0) {
        k = g + 4;
        break;
      }
    }
  }
}

}  // namespace

std::uint32_t workTileCount(int width, int height, int tileSize) {
  PP5_CHECK_GE(width, 0);
  PP5_CHECK_GE(height, 0);
  return TileGrid(width, height, tileSize).count();
}

void sampleAll(const ShadeBuffer& shade, const SampleLattice& lattice, const RenderSettings& settings,
               SampleSink& sink, const EmptySpaceMap* space, const SamplerOptions& options) {
  checkSameGrid(shade.grid(), lattice.grid());
  PP5_CHECK_GT(options.batchSamples, std::size_t{0});
  const int W = lattice.width(), H = lattice.height();
  const TileGrid tiles(W, H, options.tileSize);
  const TileSelection selection(tiles, options.workTiles);
  const std::int64_t workCount =
      selection.all ? static_cast<std::int64_t>(tiles.count()) : static_cast<std::int64_t>(selection.list.size());
  std::optional<OwnedCells> owned;
  if (options.ownedCells) owned.emplace(*options.ownedCells, lattice.grid().dims - Index3(1));
  if (workCount == 0 || (owned && owned->empty())) return;
  EmptySpaceMap own;
  if (!space) {
    own = EmptySpaceMap(shade, settings.threads);
    space = &own;
  }
  checkSameGrid(space->grid(), lattice.grid());
  const Interpolator interp(shade);
  const float e = exponentOf(lattice, settings);
  const std::uint8_t* dist = space->distances();
  const Index3 bd = space->brickDims();
  const Box3 occupied = space->occupiedCells();
  if (occupied.empty()) return;
  // A visible sample's cell is in the visible bricks' bounds: where those
  // miss the owned cells, every owned sample is transparent.
  if (owned && owned->box().intersect(occupied).empty()) return;
  // Where a ray is walked: the visible bricks' bounds grown by the margin,
  // and with ownedCells the part of it that can hold an owned cell. (The two
  // boxes meet, so the clip below gives the intersection of their ranges.)
  double clipLo[3], clipHi[3];
  for (int a = 0; a < 3; ++a) {
    clipLo[a] = occupied.lo[a] - kSkipMarginVoxels;
    clipHi[a] = occupied.hi[a] + kSkipMarginVoxels;
    if (owned) {
      clipLo[a] = std::max(clipLo[a], owned->lo(a));
      clipHi[a] = std::min(clipHi[a], owned->hi(a));
    }
  }
  const int nt = static_cast<int>(std::min<std::int64_t>(threadCount(settings.threads), workCount));

#pragma omp parallel num_threads(nt)
  {
    Batcher out(sink, omp_get_thread_num(), options.batchSamples);
    RayStage stage(lattice.maxSamples(), e);
    // This thread's copies: the walk reads them for every ray.
    const OwnedCells* const mine = owned ? &*owned : nullptr;
    const double lo[3] = {clipLo[0], clipLo[1], clipLo[2]}, hi[3] = {clipHi[0], clipHi[1], clipHi[2]};
#pragma omp for schedule(dynamic, 1)
    for (std::int64_t w = 0; w < workCount; ++w) {
      const std::int64_t t = selection.all ? w : selection.list[static_cast<std::size_t>(w)];
      out.startTile(static_cast<std::uint32_t>(t));
      const int x0 = static_cast<int>(t % tiles.nx) * tiles.size, y0 = static_cast<int>(t / tiles.nx) * tiles.size;
      const int x1 = std::min(W, x0 + tiles.size), y1 = std::min(H, y0 + tiles.size);
      for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x) {
          const auto pixel = static_cast<std::uint32_t>(y) * static_cast<std::uint32_t>(W) + static_cast<std::uint32_t>(x);
          const std::uint32_t n = lattice.count(pixel);
          if (n == 0) continue;
          const VoxelRay vr = lattice.voxelRay(pixel);
          // Only the part of the ray inside the visible bricks' bounds (grown
          // by the margin) can have a visible sample; with ownedCells, only
          // its part in the owned box (grown likewise) an owned one.
          double kIn = 0.0, kOut = static_cast<double>(n - 1);
          const BrickJump jump(vr);
          const double* inv = jump.inv;
          for (int a = 0; a < 3; ++a) {
            const double b0 = vr.base[a], dl = vr.delta[a];
            if (dl == 0.0) {
              if (b0 < lo[a] || b0 > hi[a]) kOut = -1.0;
              continue;
            }
            const double t0 = (lo[a] - b0) * inv[a], t1 = (hi[a] - b0) * inv[a];
            kIn = std::max(kIn, std::min(t0, t1));
            kOut = std::min(kOut, std::max(t0, t1));
          }
          if (!(kOut >= kIn)) continue;
          const std::uint32_t k = static_cast<std::uint32_t>(std::ceil(kIn));
          const std::uint32_t kEnd = static_cast<std::uint32_t>(kOut);  // floor: kOut >= 0
          if (k > kEnd) continue;
          if (mine) {  // the clip was conservative: now the exact cells
            std::int64_t k0 = k, k1 = kEnd;
            if (mine->exact(interp, vr, k0, k1))
              walkVisible(interp, vr, jump, dist, bd, static_cast<std::uint32_t>(k0), static_cast<std::uint32_t>(k1),
                          stage);
          } else {
            walkVisible(interp, vr, jump, dist, bd, k, kEnd, stage);
          }
          stage.emit(pixel, out);
        }
      out.flush();
    }
  }
}

void sampleRegion(const ShadeBuffer& shade, const SampleLattice& lattice, const DBuffer& dbuffer,
                  const RenderSettings& settings, SampleSink& sink, const EmptySpaceMap* space,
                  const SamplerOptions& options, const EmptySpaceMap* before) {
  checkSameGrid(shade.grid(), lattice.grid());
  PP5_CHECK(!before || space);
  if (before) {
    checkSameGrid(before->grid(), lattice.grid());
    PP5_CHECK(before->brickDims() == space->brickDims());
  }
  const std::uint8_t* distBefore = before ? before->distances() : nullptr;
  PP5_CHECK_EQ(dbuffer.width(), lattice.width());
  PP5_CHECK_EQ(dbuffer.height(), lattice.height());
  PP5_CHECK_GT(options.batchSamples, std::size_t{0});
  if (space) checkSameGrid(space->grid(), lattice.grid());
  const Interpolator interp(shade);
  const float e = exponentOf(lattice, settings);
  const std::uint8_t* dist = space ? space->distances() : nullptr;
  const Index3 bd = space ? space->brickDims() : Index3(0);
  const int W = lattice.width(), H = lattice.height();
  const TileGrid tiles(W, H, options.tileSize);
  const TileSelection selection(tiles, options.workTiles);
  std::optional<OwnedCells> owned;
  if (options.ownedCells) owned.emplace(*options.ownedCells, lattice.grid().dims - Index3(1));
  if (owned && owned->empty()) return;

  // The touched pixels of the selected tiles, by tile (a counting sort keeps
  // each tile's pixels in the D-buffer's ascending order).
  const auto touched = dbuffer.touched();
  // Each touched pixel's tile, without a division per pixel: the pixels are
  // ascending, so the row advances with them, and a column table gives the
  // tile column.
  std::vector<std::uint32_t> tileOf(touched.size());
  {
    std::vector<std::uint32_t> tileColumn(static_cast<std::size_t>(W));
    for (int x = 0; x < W; ++x) tileColumn[static_cast<std::size_t>(x)] = static_cast<std::uint32_t>(x / tiles.size);
    const auto w = static_cast<std::uint32_t>(W);
    std::uint32_t y = 0, rowStart = 0;
    for (std::size_t i = 0; i < touched.size(); ++i) {
      const std::uint32_t p = touched[i];
      PP5_CHECK(i == 0 || p > touched[i - 1]);
      while (p - rowStart >= w) {
        ++y;
        rowStart += w;
      }
      tileOf[i] = (y / static_cast<std::uint32_t>(tiles.size)) * static_cast<std::uint32_t>(tiles.nx) +
                  tileColumn[p - rowStart];
    }
  }
  const std::uint8_t* mask = selection.all ? nullptr : options.workTiles.data();
  std::vector<std::uint32_t> start(tiles.count() + 1, 0);
  for (std::size_t i = 0; i < touched.size(); ++i) {
    const std::uint32_t t = tileOf[i];
    if (!mask || mask[t] != 0) ++start[t + 1];
  }
  std::vector<std::uint32_t> work;
  for (std::uint32_t t = 0; t < tiles.count(); ++t) {
    if (start[t + 1] > 0) work.push_back(t);
    start[t + 1] += start[t];
  }
  std::vector<std::uint32_t> order(start.back());
  {
    std::vector<std::uint32_t> pos(start.begin(), start.end() - 1);
    for (std::size_t i = 0; i < touched.size(); ++i) {
      const std::uint32_t t = tileOf[i];
      if (!mask || mask[t] != 0) order[pos[t]++] = touched[i];
    }
  }
  const double invStep = 1.0 / lattice.step();
  // The D-buffer has the touched pixels' perspective rays; the same camera's
  // are the lattice's, bit for bit.
  const Vec3* dirs = dbuffer.rays().camera() == lattice.camera() ? dbuffer.touchedDirs() : nullptr;
  const Vec3 eye = lattice.camera().eye;
  const int nt = std::max(1, std::min<int>(threadCount(settings.threads), static_cast<int>(work.size())));

#pragma omp parallel num_threads(nt)
  {
    Batcher out(sink, omp_get_thread_num(), options.batchSamples);
    RayStage stage(lattice.maxSamples(), e);
    const OwnedCells* const mine = owned ? &*owned : nullptr;  // this thread's copy
#pragma omp for schedule(dynamic, 1)
    for (std::int64_t w = 0; w < static_cast<std::int64_t>(work.size()); ++w) {
      const std::uint32_t t = work[static_cast<std::size_t>(w)];
      out.startTile(t);
      for (std::uint32_t i = start[t]; i < start[t + 1]; ++i) {
        const std::uint32_t pixel = order[i];
        const std::int64_t n = lattice.count(pixel);
        if (n == 0) continue;
        const VoxelRay vr = dirs ? lattice.voxelRay(pixel, Ray{eye, dirs[pixel]}) : lattice.voxelRay(pixel);
        // The ray's owned samples, [own0, own1] (all of them without ownedCells).
        std::int64_t own0 = 0, own1 = n - 1;
        if (mine) {
          double kIn = 0.0, kOut = static_cast<double>(n - 1);
          for (int a = 0; a < 3; ++a) {
            const double b0 = vr.base[a], dl = vr.delta[a];
            if (dl == 0.0) {
              if (b0 < mine->lo(a) || b0 > mine->hi(a)) kOut = -1.0;
              continue;
            }
            const double inv = 1.0 / dl;
            const double ta = (mine->lo(a) - b0) * inv, tb = (mine->hi(a) - b0) * inv;
            kIn = std::max(kIn, std::min(ta, tb));
            kOut = std::min(kOut, std::max(ta, tb));
          }
          if (!(kOut >= kIn)) continue;
          own0 = static_cast<std::int64_t>(std::ceil(kIn));
          own1 = static_cast<std::int64_t>(kOut);  // floor: kOut >= 0
          if (!mine->exact(interp, vr, own0, own1)) continue;
        }
        const double t0 = lattice.t0(pixel);
        std::int64_t done = -1;  // spans are disjoint, but rounding must not repeat a sample
        Cells4 c, next;
        Interpolator::Voxels vox{};
        std::int64_t loaded = -1;
        for (const DBuffer::Span& sp : dbuffer.spans(pixel)) {
          const std::int64_t k0 = std::max<std::int64_t>(
              done + 1, static_cast<std::int64_t>(std::clamp(std::ceil((sp.tIn - t0) * invStep), 0.0, 65536.0)));
          const double hiK = std::floor((sp.tOut - t0) * invStep);
          if (hiK < 0.0) continue;
          const std::int64_t k1 = std::min<std::int64_t>(n - 1, static_cast<std::int64_t>(std::min(hiK, 65535.0)));
          if (k0 > k1) continue;
          // The owned part of the span: which samples of it are emitted does
          // not depend on where the walk starts, so this is the unrestricted
          // output filtered.
          const std::int64_t s0 = std::max(k0, own0), s1 = std::min(k1, own1);
          if (s0 > s1) {
            done = std::max(done, k1);
            continue;
          }
          if (distBefore) {
            // Water around the object is empty in both maps: jump over the
            // cube of bricks both know to be empty (as sampleAll does). The
            // rest goes four samples at a time; a sample is emitted when its
            // brick is occupied in either map (zero where only the old map
            // had it), whichever path reaches it.
            const BrickJump jump(vr);
            std::int64_t g = s0;
            interp.locate4(vr, static_cast<std::uint32_t>(g), c);
            while (g <= s1) {
              const int b[3] = {c.i[0][0] >> kBrickShift, c.i[1][0] >> kBrickShift, c.i[2][0] >> kBrickShift};
              const std::size_t brick0 = brickOf(c, 0, bd);
              const int d = std::min<int>(dist[brick0], distBefore[brick0]);
              if (d > 0) {
                g = jump.next(b, d, g, s1);
                if (g <= s1) interp.locate4(vr, static_cast<std::uint32_t>(g), c);
                continue;
              }
              if (g + 4 <= s1) {
                interp.locate4(vr, static_cast<std::uint32_t>(g + 4), next);
                interp.prefetch(next);
              }
              const int lanes = static_cast<int>(std::min<std::int64_t>(4, s1 - g + 1));
              for (int l = 0; l < lanes; ++l) {
                const std::size_t brick = brickOf(c, l, bd);
                if (dist[brick] == 0) {
                  interp.blendLane(c, l, loaded, vox, stage.slot());
                  stage.commit(static_cast<std::uint32_t>(g + l));
                } else if (distBefore[brick] == 0) {
                  float* rgba = stage.slot();
                  rgba[0] = rgba[1] = rgba[2] = rgba[3] = 0.0f;
                  stage.commit(static_cast<std::uint32_t>(g + l));
                }
              }
              g += 4;
              std::swap(c, next);  // next holds sample g when g <= s1
            }
            done = std::max(done, k1);
            continue;
          }
          interp.locate4(vr, static_cast<std::uint32_t>(s0), c);
          for (std::int64_t g = s0; g <= s1; g += 4) {
            if (g + 4 <= s1) {
              interp.locate4(vr, static_cast<std::uint32_t>(g + 4), next);
              interp.prefetch(next);
            }
            const int lanes = static_cast<int>(std::min<std::int64_t>(4, s1 - g + 1));
            for (int l = 0; l < lanes; ++l) {
              float* rgba = stage.slot();
              if (!dist || dist[brickOf(c, l, bd)] == 0) {
                interp.blendLane(c, l, loaded, vox, rgba);
              } else {
                rgba[0] = rgba[1] = rgba[2] = rgba[3] = 0.0f;
              }
              stage.commit(static_cast<std::uint32_t>(g + l));
            }
            std::swap(c, next);
          }
          done = std::max(done, k1);
        }
        stage.emit(pixel, out);
      }
      out.flush();
    }
  }
}

RaySample sampleAt(const ShadeBuffer& shade, const SampleLattice& lattice, const RenderSettings& settings,
                   std::uint32_t pixel, std::uint32_t k) {
  checkSameGrid(shade.grid(), lattice.grid());
  const Interpolator interp(shade);
  RayStage stage(1, exponentOf(lattice, settings));
  Cells4 c;
  interp.locate4(lattice.voxelRay(pixel), k, c);
  interp.at(c, 0, stage.slot());
  stage.commit(k);
  SampleCollector one;
  Batcher out(one, 0, 1);
  stage.emit(pixel, out);
  out.flush();
  return one.samples().at(0);
}

Index3 stencilCell(const SampleLattice& lattice, std::uint32_t pixel, std::uint32_t k) {
  const Index3& d = lattice.grid().dims;
  const glm::vec3 p = lattice.voxelRay(pixel).at(k);
  Index3 c;
  for (int a = 0; a < 3; ++a) {
    std::int64_t i = static_cast<int>(p[a]);
    c[a] = std::clamp<std::int64_t>(i, 0, d[a] - 2);
  }
  return c;
}

}  // namespace pp5::gp
