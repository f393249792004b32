#pragma once
// Hole filling for the pixel methods (PLUS's vtkIGSIOFillHolesInVolume, as
// specified in docs/notes/plus-reconstruction.md, section 6).
//
// A hole is a voxel with zero accumulated weight. Its value is computed from
// the *unfilled* reconstruction only - the values and weights of known voxels
// around it - never from other filled holes, so the result does not depend on
// the order in which holes are visited, on threads, or on when (during or
// after the reconstruction) the filling runs. A hole's value depends only on
// voxels within `reach()` voxels (Chebyshev distance), which is what lets the
// reconstructor refill only the holes near each frame's dirty region.
//
// The elements (kernels) are tried in order; the first that succeeds sets the
// hole, and a hole that none fills is 0.
//  - STICK(L, N): 13 lines through the hole; along each, the nearest known
//    voxel forwards (within L-1 steps) and then backwards (within the rest of
//    the length); the N shortest sticks (all of equal weight together) are
//    averaged with weight 1 / (length * |direction|).
//  - GAUSSIAN(Size, Stdev, ratio), GAUSSIAN_ACCUMULATION (weight x Gaussian),
//    DISTANCE_WEIGHT_INVERSE (1 / distance): weighted mean of the known voxels
//    in a Size^3 cube, if more than `ratio` of the cube is known.
//  - NEAREST_NEIGHBOR(Size, ratio): mean of the known voxels in the smallest
//    cube (radius 1 .. Size/2) that holds any, if more than `ratio` of Size^3.
//
// Two arithmetics, as for the reconstruction:
//  - plus: PLUS's exactly - stick values and results truncated to 8-bit grey
//    levels, and its stick interpolation weights (rvs+1)/(fwd+rvs+1), which
//    place the hole one step closer to the forward voxel than it is;
//  - float: no truncation, and a stick interpolates linearly by the true
//    distances (weight rvs/(fwd+rvs) on the forward value).
// The Gaussian, inverse-distance and nearest-neighbour kernels follow the spec
// as read from PLUS's source (no PLUS baseline covers them): float kernels,
// double sums.
#include <cmath>
#include <cstdint>
#include <vector>

#include "core/grid.hpp"
#include "formats/plus_config.hpp"
#include "formats/volume_io.hpp"
#include "reconstruction/dirty_region.hpp"

namespace pp5::gp {

class HoleFiller {
public:
  // Throws InputError for parameters PLUS would not run with (Size < 1,
  // Stdev <= 0, StickLengthLimit < 1, NumberOfSticksToUse < 1).
  HoleFiller(const std::vector<PlusHoleFillingElement>& elements, bool plusArithmetic);

  // What `fill_holes` uses when a config names no elements: STICK, length 9, one stick.
  static std::vector<PlusHoleFillingElement> defaultElements();

  // A hole's value depends only on known voxels within this many voxels.
  int reach() const { return reach_; }
  bool plusArithmetic() const { return plus_; }

  // The value of hole (x, y, z). `Src` is the unfilled reconstruction:
  //   bool known(std::size_t i); float value(std::size_t i); float weight(std::size_t i)
  // with i the x-fastest linear index on a grid of `dims`.
  template <class Src>
  float fill(const Src& src, const Index3& dims, std::int64_t x, std::int64_t y, std::int64_t z) const {
    float v = 0.0f;
    return tryFill(src, dims, x, y, z, v) ? v : 0.0f;
  }
  // As fill(), but says whether an element succeeded (out is 0 when none did).
  template <class Src>
  bool tryFill(const Src& src, const Index3& dims, std::int64_t x, std::int64_t y, std::int64_t z, float& out) const;

private:
  struct Element {
    PlusHoleFillingElement e;
    int half = 0;                // cube radius (Size-1)/2
    std::vector<float> kernel;   // Size^3, x fastest (GAUSSIAN*, DISTANCE_WEIGHT_INVERSE)
  };
  template <class Src>
  bool stick(const Src& src, const Index3& dims, const Element& el, std::int64_t x, std::int64_t y, std::int64_t z,
             float& out) const;
  template <class Src>
  bool weighted(const Src& src, const Index3& dims, const Element& el, std::int64_t x, std::int64_t y,
                std::int64_t z, float& out) const;
  template <class Src>
  bool nearest(const Src& src, const Index3& dims, const Element& el, std::int64_t x, std::int64_t y,
               std::int64_t z, float& out) const;
  double finish(double v) const { return plus_ ? std::trunc(v) : v; }

  std::vector<Element> elements_;
  bool plus_ = false;
  int reach_ = 0;
};

// Convenience (tests, offline use): fills every hole of an unfilled F32 volume
// whose F32 `weights` are 0 at holes; known voxels are copied.
Volume fillHoles(const Volume& unfilled, const Volume& weights, const std::vector<PlusHoleFillingElement>& elements,
                 bool plusArithmetic);

// ---- implementation ----

namespace holefill_detail {
// PLUS's stick directions, in its order (the order decides nothing, since
// sticks of equal weight are used together, but it keeps the code comparable).
inline constexpr int kStickDirs[13][3] = {{1, 0, 0},  {0, 1, 0},  {0, 0, 1},  {1, 1, 0},   {1, 0, 1},
                                          {0, 1, 1},  {1, -1, 0}, {1, 0, -1}, {0, 1, -1},  {1, 1, 1},
                                          {-1, 1, 1}, {1, -1, 1}, {-1, -1, 1}};
inline bool inside(const Index3& d, std::int64_t x, std::int64_t y, std::int64_t z) {
  return x >= 0 && y >= 0 && z >= 0 && x < d.x && y < d.y && z < d.z;
}
inline std::size_t lin(const Index3& d, std::int64_t x, std::int64_t y, std::int64_t z) {
  return static_cast<std::size_t>((z * d.y + y) * d.x + x);
}
}  // namespace holefill_detail

template <class Src>
bool HoleFiller::tryFill(const Src& src, const Index3& dims, std::int64_t x, std::int64_t y, std::int64_t z,
                         float& out) const {
  float v = 0.0f;
  for (const Element& el : elements_) {
    bool ok = false;
    switch (el.e.type) {
      case PlusHoleFillingType::Stick: ok = stick(src, dims, el, x, y, z, v); break;
      case PlusHoleFillingType::NearestNeighbor: ok = nearest(src, dims, el, x, y, z, v); break;
      case PlusHoleFillingType::Gaussian:
      case PlusHoleFillingType::GaussianAccumulation:
      case PlusHoleFillingType::DistanceWeightInverse: ok = weighted(src, dims, el, x, y, z, v); break;
    }
    if (ok) {
      out = v;
      return true;
    }
  }
  out = 0.0f;
  return false;
}

template <class Src>
bool HoleFiller::stick(const Src& src, const Index3& dims, const Element& el, std::int64_t x, std::int64_t y,
                       std::int64_t z, float& out) const {
  using namespace holefill_detail;
  const int L = el.e.stickLengthLimit;
  double value[13], weight[13];
  bool any = false;
  for (int s = 0; s < 13; ++s) {
    weight[s] = 0.0;
    const int dx = kStickDirs[s][0], dy = kStickDirs[s][1], dz = kStickDirs[s][2];
    int fwd = 0;
    double vf = 0.0;
    for (int k = 1; k <= L - 1; ++k) {
      const std::int64_t px = x + k * dx, py = y + k * dy, pz = z + k * dz;
      if (!inside(dims, px, py, pz)) break;
      const std::size_t i = lin(dims, px, py, pz);
      if (src.known(i)) {
        fwd = k;
        vf = src.value(i);
        break;
      }
    }
    if (fwd == 0) continue;
    int rvs = 0;
    double vr = 0.0;
    for (int k = 1; k <= L - 1 - fwd; ++k) {
      const std::int64_t px = x - k * dx, py = y - k * dy, pz = z - k * dz;
      if (!inside(dims, px, py, pz)) break;
      const std::size_t i = lin(dims, px, py, pz);
      if (src.known(i)) {
        rvs = k;
        vr = src.value(i);
        break;
      }
    }
    if (rvs == 0) continue;
    const double total = fwd + rvs + 1;
    if (plus_) {
      const double wf = (rvs + 1) / total;
      const double wr = 1.0 - wf;
      value[s] = std::trunc(wr * vr + wf * vf);
    } else {
      const double wf = double(rvs) / double(fwd + rvs);
      value[s] = (1.0 - wf) * vr + wf * vf;
    }
    weight[s] = 1.0 / (total * std::sqrt(double(dx * dx + dy * dy + dz * dz)));
    any = true;
  }
  if (!any) return false;
  // The shortest sticks first; all sticks of the current best weight together.
  double sv = 0.0, sw = 0.0;
  int used = 0;
  while (used < el.e.numberOfSticksToUse) {
    double best = 0.0;
    for (double w : weight) best = std::max(best, w);
    if (best == 0.0) break;
    for (int s = 0; s < 13; ++s)
      if (weight[s] == best) {
        sv += value[s] * weight[s];
        sw += weight[s];
        weight[s] = 0.0;
        ++used;
      }
  }
  out = static_cast<float>(finish(sv / sw));
  return true;
}

template <class Src>
bool HoleFiller::weighted(const Src& src, const Index3& dims, const Element& el, std::int64_t x, std::int64_t y,
                          std::int64_t z, float& out) const {
  using namespace holefill_detail;
  const int S = el.e.size, h = el.half;
  const bool byWeight = el.e.type == PlusHoleFillingType::GaussianAccumulation;
  double sum = 0.0, sumK = 0.0;
  std::int64_t count = 0;
  for (int dz = -h; dz <= h; ++dz)
    for (int dy = -h; dy <= h; ++dy)
      for (int dx = -h; dx <= h; ++dx) {
        const std::int64_t px = x + dx, py = y + dy, pz = z + dz;
        if (!inside(dims, px, py, pz)) continue;
        const std::size_t i = lin(dims, px, py, pz);
        if (!src.known(i)) continue;
        double k = el.kernel[static_cast<std::size_t>(((dz + h) * S + (dy + h)) * S + (dx + h))];
        if (byWeight) k *= src.weight(i);
        sum += src.value(i) * k;
        sumK += k;
        ++count;
      }
  if (sumK == 0.0) return false;
  if (!(double(count) / (double(S) * S * S) > el.e.minRatio)) return false;
  out = static_cast<float>(finish(sum / sumK));
  return true;
}

template <class Src>
bool HoleFiller::nearest(const Src& src, const Index3& dims, const Element& el, std::int64_t x, std::int64_t y,
                         std::int64_t z, float& out) const {
  using namespace holefill_detail;
  const int S = el.e.size;
  double sum = 0.0;
  std::int64_t count = 0;
  for (int r = 1; r <= el.half && count == 0; ++r)
    for (int dz = -r; dz <= r; ++dz)
      for (int dy = -r; dy <= r; ++dy)
        for (int dx = -r; dx <= r; ++dx) {
          const std::int64_t px = x + dx, py = y + dy, pz = z + dz;
          if (!inside(dims, px, py, pz)) continue;
          const std::size_t i = lin(dims, px, py, pz);
          if (!src.known(i)) continue;
          sum += src.value(i);
          ++count;
        }
  if (count == 0 || !(double(count) / (double(S) * S * S) > el.e.minRatio)) return false;
  out = static_cast<float>(finish(sum / double(count)));
  return true;
}

}  // namespace pp5::gp
