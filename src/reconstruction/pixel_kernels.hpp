#pragma once
// The kernels of the PLUS-compatible pixel splatting (reconstruction/splat_pixel.cpp):
// nearest neighbour and trilinear, each with MEAN / LATEST / MAXIMUM
// compounding, in PLUS's own arithmetic ("plus") or in exact float arithmetic
// ("float"), over one thread's slab of the grid. Internal to splat_pixel; the
// reconstructor owns the cells and the threads.
#include <cstdint>
#include <vector>

#include "core/grid.hpp"
#include "reconstruction/dirty_region.hpp"
#include "reconstruction/fan_mask.hpp"
#include "reconstruction/fixed_point.hpp"
#include "reconstruction/reconstruction.hpp"

namespace pp5::gp::pixel {

// "plus" state: PLUS's 8-bit value and 16-bit accumulator (256 = one full
// pixel), side by side so one cache line holds both.
struct PlusCell {
  std::uint8_t v;
  std::uint8_t pad;
  std::uint16_t a;
};
// "float" state: MEAN keeps the weighted sum in `s`; LATEST and MAXIMUM keep
// the value. `w` is the total weight (0 = not covered). Sums of 8-bit values
// with unit weights stay exact up to 65793 hits.
struct FloatCell {
  float s;
  float w;
};
static_assert(sizeof(PlusCell) == 4 && sizeof(FloatCell) == 8);

// Trilinear LATEST / MAXIMUM: a pixel sets a voxel only where its weight there
// is at least 1/8 (PLUS's rule, §4).
constexpr float kMinWeightFloat = 0.125f;
constexpr std::int32_t kMinWeightFixed = plusmath::kOne / 8;

// Voxel coordinates of pixel (i, j): O + j*Y + i*X.
struct PixelMap {
  double O[3], X[3], Y[3];
};
struct FixedMap {
  std::int64_t O[3], X[3], Y[3];
};

// Voxels [lo, hi) along `axis` belong to one thread.
struct Slab {
  int axis = 2;
  std::int64_t lo = 0, hi = 0;
};

struct SlabOut {
  std::uint64_t pixels = 0;
  std::vector<std::uint64_t> prefix;  // scratch: per-row prefix sums
  std::vector<std::uint32_t> prefix32;
  std::vector<std::uint32_t> count;
  std::vector<std::uint8_t> marks;    // scratch of walkRunFloat, zero between rows
  // The voxels this slab wrote since the last output update, each once, and
  // their bricks: the output is refreshed at exactly these, and their bricks
  // are the dirty region.
  std::vector<std::int64_t> written;
  std::vector<std::uint32_t> writtenBrick;
  std::size_t nWritten = 0;
  void reserveWritten(std::size_t extra) {
    if (written.size() >= nWritten + extra) return;
    const std::size_t n = std::max(nWritten + extra, 2 * written.size());
    written.resize(n);
    writtenBrick.resize(n);
  }
};

// What every kernel reads, for one frame.
struct Job {
  Index3 dims{0};
  std::int64_t sy = 0, sz = 0;  // voxel strides
  const std::vector<PixelRun>* runs = nullptr;
  const std::uint8_t* pixels = nullptr;  // row-major; U16 little-endian on a little-endian host
  int width = 0;
  bool u16 = false;
  int rejectBelow = 0;  // pixels darker than this are not inserted
  PixelMap map{};
  FixedMap fmap{};
  std::uint8_t* touched = nullptr;  // per voxel: listed in a SlabOut's `written`
  std::int64_t bx = 0, bxy = 0;     // brick strides (bricks of 16 voxels)
};

static_assert(DirtyRegion::kDefaultBrick == 16);

// Positions are checked to stay below this (insert), so every conversion to
// int64 is defined.
constexpr double kPositionLimit = 1125899906842624.0;  // 2^50

// One slab's share of a frame: the kernel of `method` with `comp`, on cells
// in PLUS's arithmetic or in float (for 8- or 16-bit pixels, job.u16).
void splatPlus(Method method, Compounding comp, const Job& job, PlusCell* cells, const Slab& slab, bool split,
               SlabOut& out);
void splatFloat(Method method, Compounding comp, const Job& job, FloatCell* cells, const Slab& slab, bool split,
                SlabOut& out);

}  // namespace pp5::gp::pixel
