#include "gp/sample_lattice.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <omp.h>

#include "core/error.hpp"

namespace pp5::gp {

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

SampleLattice::SampleLattice(const Camera& camera, const Grid& grid, double step, int maxSamples, int threads)
    : rays_(camera), grid_(grid), step_(step), maxSamples_(maxSamples) {
  PP5_CHECK_GT(step, 0.0);
  PP5_CHECK_GE(maxSamples, 1);
  PP5_CHECK_LE(maxSamples, 65535);
  PP5_CHECK_GE(grid.dims.x, 1);
  PP5_CHECK_GE(grid.dims.y, 1);
  PP5_CHECK_GE(grid.dims.z, 1);
  const auto W = static_cast<std::uint32_t>(camera.width), H = static_cast<std::uint32_t>(camera.height);
  t0_.assign(static_cast<std::size_t>(W) * H, 0.0f);
  count_.assign(static_cast<std::size_t>(W) * H, 0);
  const Vec3 lo = boxMin(), hi = boxMax();
  const int nt = threads > 0 ? threads : std::max(1, omp_get_max_threads());
#pragma omp parallel for num_threads(nt) schedule(static)
  for (std::int64_t y = 0; y < static_cast<std::int64_t>(H); ++y) {
    for (std::uint32_t x = 0; x < W; ++x) {
      const std::size_t p = static_cast<std::size_t>(y) * W + x;
      double tIn, tOut;
      if (!intersectBox(rays_.ray(static_cast<int>(x), static_cast<int>(y)), lo, hi, tIn, tOut)) continue;
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

SampleLattice::SampleLattice(const RenderSettings& s, const Grid& grid)
    : SampleLattice(makeCamera(s, grid), grid, s.step(grid), s.maxSamples, s.threads) {}

std::uint64_t SampleLattice::totalSamples() const {
  std::uint64_t n = 0;
  for (const auto c : count_) n += c;
  return n;
}

Vec3 SampleLattice::point(std::uint32_t pixel, std::uint32_t k) const {
  const Ray r = rays_.ray(pixel);
  return r.origin + r.dir * t(pixel, k);
}

VoxelRay SampleLattice::voxelRay(std::uint32_t pixel) const {
  const Ray r = rays_.ray(pixel);
  const Vec3 o = (r.origin - grid_.origin) / grid_.spacing;
  const Vec3 d = r.dir / grid_.spacing;
  return {glm::vec3(o + d * static_cast<double>(t0_[pixel])), glm::vec3(d * step_)};
}

}  // namespace pp5::gp
