#pragma once
// The global sample lattice (docs/architecture.md): the ray of pixel p takes
// its samples at t_k = t0(p) + k * step, k < count(p), t along the ray's unit
// direction. t0(p) is where the ray enters the grid's sampling box, so sample
// k of pixel p is the same point on every rank and has one home in the PP's
// cache, whichever brick, box or GP produced it.
//
// The sampling box is the box of the voxel centres, [Grid::minCorner(),
// Grid::maxCorner()]: trilinear interpolation has all eight neighbours there
// and nowhere else, so no sample needs a clamped or invented voxel. (The half
// voxel beyond it, out to the voxels' outer faces, would need an edge rule.)
// t0 is clamped to >= 0 for both projections: a ray starts at the eye
// (perspective) or on the eye's plane (orthographic), and an eye inside the
// box starts its rays where it is.
//
// The lattice is a pure function of (camera, grid, step, maxSamples, pixel
// stride), with the same double arithmetic on every rank; it stores t0 as a
// float (rounded up, so that sample 0 is never in front of the box) and count
// as a uint16. With a pixel stride s > 1 (the viewer's fast image while the
// user drags), only pixels whose x and y are multiples of s have rays: every
// other pixel's count is 0, and the image is s times coarser (fillStride).
#include <cstdint>
#include <span>
#include <vector>

#include <glm/glm.hpp>

#include "core/camera.hpp"
#include "core/grid.hpp"
#include "core/render_settings.hpp"

namespace pp5 {

// The ray of every pixel of a camera's image, from a basis computed once.
// ray() repeats Camera::ray's arithmetic step for step, so its rays are
// bitwise Camera::pixelRay's, without recomputing the basis per pixel. The
// lattice, the D-buffer and the sampler all take their rays from here.
class PixelRays {
public:
  PixelRays() = default;
  explicit PixelRays(const Camera& camera);

  const Camera& camera() const { return cam_; }
  int width() const { return cam_.width; }
  int height() const { return cam_.height; }
  bool perspective() const { return cam_.projection == Projection::Perspective; }
  const Vec3& forward() const { return f_; }
  const Vec3& right() const { return r_; }
  const Vec3& up() const { return u_; }

  Ray ray(int x, int y) const;
  // Where the rays of pixels x0 .. x1 - 1 of row y enter and leave the box
  // [lo, hi]: for each, hit (0 or 1) and, on a hit, tIn <= tOut; bitwise
  // intersectBox(ray(x, y), lo, hi, ...), two pixels at a time.
  void rowThroughBox(int y, int x0, int x1, const Vec3& lo, const Vec3& hi, double* tIn, double* tOut,
                     std::uint8_t* hit) const;
  Ray ray(std::uint32_t pixel) const {
    return ray(static_cast<int>(pixel % static_cast<std::uint32_t>(cam_.width)),
               static_cast<int>(pixel / static_cast<std::uint32_t>(cam_.width)));
  }
  // A world point in camera space: (right, up, forward) relative to the eye;
  // z is the depth along forward().
  Vec3 toCamera(const Vec3& world) const;
  // Continuous pixel coordinates of a camera-space point, as Camera::project
  // computes them; perspective needs z > 0.
  glm::dvec2 toPixel(const Vec3& cameraSpace) const;

private:
  Camera cam_;
  Vec3 f_{0.0, 0.0, -1.0}, r_{1.0, 0.0, 0.0}, u_{0.0, 1.0, 0.0};
  double h_ = 1.0, w_ = 1.0;  // half-height and half-width of the image plane
};

// [tEnter, tExit] of the line origin + t dir (every t, negative too) in the
// closed box [lo, hi]; false when it misses. A direction component of zero is
// handled exactly (no 0 * inf).
bool intersectBox(const Ray& ray, const Vec3& lo, const Vec3& hi, double& tEnter, double& tExit);

// A ray in voxel coordinates (Grid::worldToVoxel), as the sampler walks it:
// sample k is at base + float(k) * delta, in float. Computing each position
// from k, rather than by adding delta k times, gives sample k the same bits
// whichever k a walk starts from (sampleAll and sampleRegion agree).
struct VoxelRay {
  glm::vec3 base{0.0f};   // sample 0
  glm::vec3 delta{0.0f};  // one step
  glm::vec3 at(std::uint32_t k) const { return base + static_cast<float>(k) * delta; }
};

class SampleLattice {
public:
  SampleLattice() = default;
  // threads: 0 = every core; the lattice does not depend on it.
  // pixelStride: 1 .. 64.
  SampleLattice(const Camera& camera, const Grid& grid, double step, int maxSamples, int threads = 0,
                int pixelStride = 1);
  // makeCamera(s, grid), s.step(grid), s.maxSamples, s.threads, s.pixelStride.
  SampleLattice(const RenderSettings& s, const Grid& grid);

  const Camera& camera() const { return rays_.camera(); }
  const PixelRays& rays() const { return rays_; }
  const Grid& grid() const { return grid_; }
  double step() const { return step_; }
  int maxSamples() const { return maxSamples_; }
  int pixelStride() const { return stride_; }
  int width() const { return rays_.width(); }
  int height() const { return rays_.height(); }
  std::uint32_t pixelCount() const { return static_cast<std::uint32_t>(t0_.size()); }
  // The sampling box (voxel centres).
  Vec3 boxMin() const { return grid_.minCorner(); }
  Vec3 boxMax() const { return grid_.maxCorner(); }

  float t0(std::uint32_t pixel) const { return t0_[pixel]; }
  std::uint16_t count(std::uint32_t pixel) const { return count_[pixel]; }
  // Per pixel, row-major over the whole image (a PP's RayCache takes its
  // tile's rows of counts()).
  std::span<const float> t0s() const { return t0_; }
  std::span<const std::uint16_t> counts() const { return count_; }
  std::uint64_t totalSamples() const;

  double t(std::uint32_t pixel, std::uint32_t k) const { return static_cast<double>(t0_[pixel]) + k * step_; }
  // World position of sample k of `pixel` (double; the sampler's float
  // position voxelRay(pixel).at(k) is within a few float ulps of it).
  Vec3 point(std::uint32_t pixel, std::uint32_t k) const;
  VoxelRay voxelRay(std::uint32_t pixel) const { return voxelRay(pixel, rays_.ray(pixel)); }
  // The same from the pixel's ray, when the caller has it (rays().ray(pixel)).
  VoxelRay voxelRay(std::uint32_t pixel, const Ray& r) const;

private:
  PixelRays rays_;
  Grid grid_;
  double step_ = 1.0;
  int maxSamples_ = 0;
  int stride_ = 1;
  std::vector<float> t0_;
  std::vector<std::uint16_t> count_;
};

}  // namespace pp5
