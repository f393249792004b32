#pragma once
// Where a sweep's work lies, counted once on the serial pipeline so that the
// benchmark's cost model can say how much of it any GP / PP layout gives each
// rank without running that layout (benchmark/cost_fit.hpp).
//
// Per incremental frame it adds up:
//  - the reconstruction's dirty voxels, by voxel layer along each grid axis
//    (a slab GP reconstructs the layers of its window), and each frame's
//    dirty layer range per axis (whether a slab GP gets the frame's pixels);
//  - the dirty voxels also by the screen footprint of their brick (a tile GP's
//    change tracker scans the dirty bricks its tiles see, so a brick counts
//    for every GP whose tiles its footprint touches);
//  - the voxels re-shaded, by layer along each axis;
//  - the lattice samples re-sampled, by (screen bin, cell layer) along each
//    axis (a slab GP samples its cells, a tile GP and a PP their tiles).
// Screen bins are squares of `binPx` pixels; the layouts' tiles must be
// multiples of it.
#include <array>
#include <cstdint>
#include <map>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "core/grid.hpp"
#include "core/ray_sample.hpp"
#include "core/sample_lattice.hpp"
#include "reconstruction/dirty_region.hpp"

namespace pp5::serial {

class WorkCensus {
public:
  WorkCensus(const Grid& grid, int imageWidth, int imageHeight, int binPx = 32);

  // One frame's reconstruction and shading (before its samples).
  void addFrame(const gp::DirtyRegion& dirty, const std::vector<gp::Box3>& shadedRuns, const SampleLattice& lattice,
                std::uint64_t pixelBytes);
  // Samples of the current frame; safe to call from several threads.
  void addSamples(std::span<const RaySample> samples, const SampleLattice& lattice);

  // JSON (schema "pp5echo-census-1"), the cost model's input.
  void write(const std::string& path) const;

  int binsX() const { return bx_; }
  int binsY() const { return by_; }
  std::uint64_t frames() const { return frames_; }

private:
  Grid grid_;
  int w_, h_, bin_, bx_, by_;
  std::array<std::int64_t, 3> layers_{};  // cells per axis (dims - 1, at least 1)
  std::uint64_t frames_ = 0, pixelBytes_ = 0;
  std::array<std::vector<double>, 3> recon_, shaded_;  // [axis][voxel layer]
  std::array<std::vector<double>, 3> samples_;         // [axis][bin * layers + cell layer]
  std::vector<std::array<std::int64_t, 6>> frameRanges_;  // per frame: dirty voxel [lo, hi) per axis
  // Dirty voxels by their brick's screen footprint, in bins: key (x0, y0, x1, y1) inclusive.
  std::map<std::array<int, 4>, double> footprints_;
  std::mutex m_;
};

}  // namespace pp5::serial
