#include "pipeline/work_census.hpp"

#include <algorithm>
#include <fstream>

#include <nlohmann/json.hpp>

#include "core/error.hpp"
#include "rendering/stencil.hpp"

namespace pp5::serial {

WorkCensus::WorkCensus(const Grid& grid, int imageWidth, int imageHeight, int binPx)
    : grid_(grid), w_(imageWidth), h_(imageHeight), bin_(binPx) {
  if (binPx < 1 || imageWidth < 1 || imageHeight < 1)
    throw InputError("census: the image and its bins need at least one pixel");
  bx_ = (w_ + bin_ - 1) / bin_;
  by_ = (h_ + bin_ - 1) / bin_;
  for (int a = 0; a < 3; ++a) {
    layers_[a] = std::max<std::int64_t>(1, grid.dims[a] - 1);
    recon_[a].assign(static_cast<std::size_t>(grid.dims[a]), 0.0);
    shaded_[a].assign(static_cast<std::size_t>(grid.dims[a]), 0.0);
    samples_[a].assign(static_cast<std::size_t>(bx_ * by_ * layers_[a]), 0.0);
  }
}

void WorkCensus::addFrame(const gp::DirtyRegion& dirty, const std::vector<gp::Box3>& shadedRuns,
                          const SampleLattice& lattice, std::uint64_t pixelBytes) {
  const gp::Box3 whole{Index3(0), grid_.dims};
  ++frames_;
  pixelBytes_ = pixelBytes;
  std::array<std::int64_t, 6> range{0, 0, 0, 0, 0, 0};
  if (!dirty.empty()) {
    const gp::Box3 b = dirty.bounds().intersect(whole);
    range = {b.lo.x, b.hi.x, b.lo.y, b.hi.y, b.lo.z, b.hi.z};
  }
  frameRanges_.push_back(range);
  auto addLayers = [&](std::array<std::vector<double>, 3>& to, const gp::Box3& b) {
    if (b.empty()) return;
    const Index3 n = b.hi - b.lo;
    for (int a = 0; a < 3; ++a) {
      const double perLayer = static_cast<double>(n[(a + 1) % 3] * n[(a + 2) % 3]);
      for (std::int64_t i = b.lo[a]; i < b.hi[a]; ++i) to[a][static_cast<std::size_t>(i)] += perLayer;
    }
  };
  for (const gp::Box3& b : dirty.boxes()) addLayers(recon_, b.intersect(whole));
  for (const gp::Box3& run : shadedRuns) addLayers(shaded_, run.intersect(whole));
  // The dirty voxels by their brick's footprint: a tile GP's change tracker
  // scans the dirty bricks its tiles see.
  for (const std::uint32_t brick : dirty.bricks()) {
    const gp::Box3 b = dirty.brickBox(brick).intersect(whole);
    if (b.empty()) continue;
    std::array<int, 4> f{0, 0, bx_ - 1, by_ - 1};
    if (const auto p = gp::stencilFootprint(grid_, b, lattice.camera())) {
      if (p->x1 < 0 || p->y1 < 0 || p->x0 >= w_ || p->y0 >= h_) continue;  // off screen: no tile sees it
      // Clamped in double first: a corner near the eye's plane projects far out.
      auto binOf = [&](double px, int n) {
        return static_cast<int>(std::clamp(px, 0.0, static_cast<double>(n * bin_ - 1))) / bin_;
      };
      f = {binOf(p->x0, bx_), binOf(p->y0, by_), binOf(p->x1, bx_), binOf(p->y1, by_)};
    }
    footprints_[f] += static_cast<double>(b.voxelCount());
  }
}

void WorkCensus::addSamples(std::span<const RaySample> samples, const SampleLattice& lattice) {
  const std::lock_guard<std::mutex> lock(m_);
  for (const RaySample& s : samples) {
    const Index3 c = gp::stencilCell(lattice, s.pixel, s.k);
    const int x = static_cast<int>(s.pixel % static_cast<std::uint32_t>(w_)) / bin_;
    const int y = static_cast<int>(s.pixel / static_cast<std::uint32_t>(w_)) / bin_;
    const auto bin = static_cast<std::size_t>(y * bx_ + x);
    for (std::size_t a = 0; a < 3; ++a) {
      const auto layer = static_cast<std::size_t>(std::clamp<std::int64_t>(c[static_cast<int>(a)], 0, layers_[a] - 1));
      samples_[a][bin * static_cast<std::size_t>(layers_[a]) + layer] += 1.0;
    }
  }
}

void WorkCensus::write(const std::string& path) const {
  nlohmann::json j;
  j["schema"] = "pp5echo-census-1";
  j["grid_dims"] = {grid_.dims.x, grid_.dims.y, grid_.dims.z};
  j["image"] = {w_, h_};
  j["bin_px"] = bin_;
  j["bins"] = {bx_, by_};
  j["frames"] = frames_;
  j["frame_pixel_bytes"] = pixelBytes_;
  for (int a = 0; a < 3; ++a) {
    j["recon_voxels_by_layer"].push_back(recon_[a]);
    j["shaded_voxels_by_layer"].push_back(shaded_[a]);
    j["samples_by_bin_and_cell_layer"].push_back(samples_[a]);
  }
  j["frame_dirty_ranges"] = frameRanges_;
  nlohmann::json f = nlohmann::json::array();
  for (const auto& [k, v] : footprints_) f.push_back({k[0], k[1], k[2], k[3], v});
  j["dirty_voxels_by_footprint"] = f;
  std::ofstream out(path);
  if (!out) throw InputError("census: cannot write " + path);
  out << j.dump() << "\n";
  if (!out) throw InputError("census: writing " + path + " failed");
}

}  // namespace pp5::serial
