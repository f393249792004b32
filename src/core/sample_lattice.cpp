#include "core/sample_lattice.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <omp.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.hpp"
#include "core/threads.hpp"

namespace pp5 {

PixelRays::PixelRays(const Camera& camera) : cam_(camera) {
  PP5_CHECK_GT(cam_.width, 0);
  PP5_CHECK_GT(cam_.height, 0);
  f_ = cam_.forward();
  r_ = cam_.right();
  u_ = cam_.trueUp();
  // The same expressions as camera.cpp's halfHeight() and Camera::ray, so the
  // rays come out bitwise equal.
  h_ = cam_.projection == Projection::Perspective ? std::tan(glm::radians(cam_.fovYDeg) * 0.5)
                                                  : cam_.orthoHeightMm * 0.5;
  w_ = h_ * static_cast<double>(cam_.width) / static_cast<double>(cam_.height);
}

Ray PixelRays::ray(int x, int y) const {
  const double px = x + 0.5, py = y + 0.5;
  const double sx = (2.0 * px / cam_.width - 1.0) * w_;
  const double sy = (1.0 - 2.0 * py / cam_.height) * h_;
  if (cam_.projection == Projection::Perspective) return {cam_.eye, glm::normalize(f_ + sx * r_ + sy * u_)};
  return {cam_.eye + sx * r_ + sy * u_, f_};
}

void PixelRays::rowThroughBox(int y, int x0, int x1, const Vec3& lo, const Vec3& hi, double* tIn, double* tOut,
                              std::uint8_t* hit) const {
  int x = x0;
#if defined(__SSE2__)
  // The operations of ray() (glm's normalize is v * (1 / sqrt(dot(v, v))),
  // its dot (x x + y y) + z z) and of intersectBox, in the same order, on two
  // lanes; a lane whose direction is 0 along an axis takes the test that
  // intersectBox takes there, by masks instead of branches.
  const bool persp = cam_.projection == Projection::Perspective;
  const double py = y + 0.5;
  const double sy = (1.0 - 2.0 * py / cam_.height) * h_;
  const __m128d one = _mm_set1_pd(1.0), two = _mm_set1_pd(2.0), half = _mm_set1_pd(0.5);
  const __m128d width = _mm_set1_pd(static_cast<double>(cam_.width)), w = _mm_set1_pd(w_);
  auto sel = [](__m128d m, __m128d a, __m128d b) { return _mm_or_pd(_mm_and_pd(m, a), _mm_andnot_pd(m, b)); };
  for (; x + 2 <= x1; x += 2) {
    const __m128d px = _mm_add_pd(_mm_set_pd(static_cast<double>(x + 1), static_cast<double>(x)), half);
    const __m128d sx = _mm_mul_pd(_mm_sub_pd(_mm_div_pd(_mm_mul_pd(two, px), width), one), w);
    __m128d o[3], d[3];
    for (int a = 0; a < 3; ++a) {
      // base + sx * r + sy * u, left to right as glm evaluates it.
      const __m128d base = _mm_set1_pd(persp ? f_[a] : cam_.eye[a]);
      const __m128d v = _mm_add_pd(_mm_add_pd(base, _mm_mul_pd(sx, _mm_set1_pd(r_[a]))), _mm_set1_pd(sy * u_[a]));
      if (persp) {
        o[a] = _mm_set1_pd(cam_.eye[a]);
        d[a] = v;
      } else {
        o[a] = v;
        d[a] = _mm_set1_pd(f_[a]);
      }
    }
    if (persp) {
      const __m128d dot = _mm_add_pd(_mm_add_pd(_mm_mul_pd(d[0], d[0]), _mm_mul_pd(d[1], d[1])), _mm_mul_pd(d[2], d[2]));
      const __m128d inv = _mm_div_pd(one, _mm_sqrt_pd(dot));
      for (int a = 0; a < 3; ++a) d[a] = _mm_mul_pd(d[a], inv);
    }
    __m128d t0 = _mm_set1_pd(-std::numeric_limits<double>::infinity());
    __m128d t1 = _mm_set1_pd(std::numeric_limits<double>::infinity());
    __m128d dead = _mm_setzero_pd();
    for (int a = 0; a < 3; ++a) {
      const __m128d l = _mm_set1_pd(lo[a]), h = _mm_set1_pd(hi[a]);
      const __m128d flat = _mm_cmpeq_pd(d[a], _mm_setzero_pd());
      dead = _mm_or_pd(dead, _mm_and_pd(flat, _mm_or_pd(_mm_cmplt_pd(o[a], l), _mm_cmpgt_pd(o[a], h))));
      const __m128d ta = _mm_div_pd(_mm_sub_pd(l, o[a]), d[a]), tb = _mm_div_pd(_mm_sub_pd(h, o[a]), d[a]);
      const __m128d swap = _mm_cmpgt_pd(ta, tb);
      const __m128d near = sel(swap, tb, ta), far = sel(swap, ta, tb);
      const __m128d n0 = sel(_mm_cmplt_pd(t0, near), near, t0);  // std::max(t0, near)
      const __m128d n1 = sel(_mm_cmplt_pd(far, t1), far, t1);    // std::min(t1, far)
      t0 = sel(flat, t0, n0);
      t1 = sel(flat, t1, n1);
    }
    const int in = _mm_movemask_pd(_mm_andnot_pd(dead, _mm_cmple_pd(t0, t1)));
    _mm_storeu_pd(tIn + (x - x0), t0);
    _mm_storeu_pd(tOut + (x - x0), t1);
    hit[x - x0] = in & 1;
    hit[x - x0 + 1] = (in >> 1) & 1;
  }
#endif
  for (; x < x1; ++x) hit[x - x0] = intersectBox(ray(x, y), lo, hi, tIn[x - x0], tOut[x - x0]) ? 1 : 0;
}

Vec3 PixelRays::toCamera(const Vec3& world) const {
  const Vec3 d = world - cam_.eye;
  return {glm::dot(d, r_), glm::dot(d, u_), glm::dot(d, f_)};
}

glm::dvec2 PixelRays::toPixel(const Vec3& c) const {
  double sx = c.x, sy = c.y;
  if (cam_.projection == Projection::Perspective) {
    sx /= c.z;
    sy /= c.z;
  }
  return {(sx / w_ + 1.0) * 0.5 * cam_.width, (1.0 - sy / h_) * 0.5 * cam_.height};
}

bool intersectBox(const Ray& ray, const Vec3& lo, const Vec3& hi, double& tEnter, double& tExit) {
  double t0 = -std::numeric_limits<double>::infinity(), t1 = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    const double o = ray.origin[a], d = ray.dir[a];
    if (d == 0.0) {
      if (o < lo[a] || o > hi[a]) return false;
      continue;
    }
    double ta = (lo[a] - o) / d, tb = (hi[a] - o) / d;
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  tEnter = t0;
  tExit = t1;
  return t0 <= t1;
}

SampleLattice::SampleLattice(const Camera& camera, const Grid& grid, double step, int maxSamples, int threads,
                             int pixelStride)
    : rays_(camera), grid_(grid), step_(step), maxSamples_(maxSamples), stride_(pixelStride) {
  PP5_CHECK_GT(step, 0.0);
  PP5_CHECK_GE(pixelStride, 1);
  PP5_CHECK_LE(pixelStride, 64);
  PP5_CHECK_GE(maxSamples, 1);
  PP5_CHECK_LE(maxSamples, 65535);
  PP5_CHECK_GE(grid.dims.x, 1);
  PP5_CHECK_GE(grid.dims.y, 1);
  PP5_CHECK_GE(grid.dims.z, 1);
  const auto W = static_cast<std::uint32_t>(camera.width), H = static_cast<std::uint32_t>(camera.height);
  t0_.assign(static_cast<std::size_t>(W) * H, 0.0f);
  count_.assign(static_cast<std::size_t>(W) * H, 0);
  const Vec3 lo = boxMin(), hi = boxMax();
  const int nt = resolveThreads(threads);
#pragma omp parallel num_threads(nt)
  {
    std::vector<double> rowIn(W), rowOut(W);
    std::vector<std::uint8_t> rowHit(W);
#pragma omp for schedule(static)
  for (std::int64_t y = 0; y < static_cast<std::int64_t>(H); ++y) {
    if (y % pixelStride != 0) continue;
    rays_.rowThroughBox(static_cast<int>(y), 0, static_cast<int>(W), lo, hi, rowIn.data(), rowOut.data(),
                        rowHit.data());
    for (std::uint32_t x = 0; x < W; ++x) {
      const std::size_t p = static_cast<std::size_t>(y) * W + x;
      if (!rowHit[x] || x % static_cast<std::uint32_t>(pixelStride) != 0) continue;
      const double tIn = rowIn[x], tOut = rowOut[x];
      const double start = std::max(tIn, 0.0);
      if (tOut < start) continue;
      float t0 = static_cast<float>(start);
      if (static_cast<double>(t0) < start) t0 = std::nextafter(t0, std::numeric_limits<float>::infinity());
      const double span = tOut - static_cast<double>(t0);
      if (span < 0.0) continue;
      const double n = std::min(std::floor(span / step) + 1.0, static_cast<double>(maxSamples));
      t0_[p] = t0;
      count_[p] = static_cast<std::uint16_t>(n);
    }
  }
  }
}

SampleLattice::SampleLattice(const RenderSettings& s, const Grid& grid)
    : SampleLattice(makeCamera(s, grid), grid, s.step(grid), s.maxSamples, s.threads, s.pixelStride) {}

std::uint64_t SampleLattice::totalSamples() const {
  std::uint64_t n = 0;
  for (const auto c : count_) n += c;
  return n;
}

Vec3 SampleLattice::point(std::uint32_t pixel, std::uint32_t k) const {
  const Ray r = rays_.ray(pixel);
  return r.origin + r.dir * t(pixel, k);
}

VoxelRay SampleLattice::voxelRay(std::uint32_t pixel, const Ray& r) const {
  const Vec3 o = (r.origin - grid_.origin) / grid_.spacing;
  const Vec3 d = r.dir / grid_.spacing;
  return {glm::vec3(o + d * static_cast<double>(t0_[pixel])), glm::vec3(d * step_)};
}

}  // namespace pp5
