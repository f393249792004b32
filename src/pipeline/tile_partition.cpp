// The tile (screen-space) partitioning: every GP reconstructs the whole grid,
// and shades and samples only what its own screen tiles (tileOwner over the
// GPs) can see: the bricks whose samples project into them, and the rays of
// their work tiles. Every frame's pixels go to every GP.
#include "pipeline/partition.hpp"

#include <algorithm>
#include <cmath>

#include "rendering/stencil.hpp"

namespace pp5::parallel {

namespace {

class TileShare final : public gp::GpShare {
public:
  TileShare(const Grid& grid, std::vector<TileRect> rects, std::vector<std::uint8_t> workTiles, int workTile)
      : grid_(grid), rects_(std::move(rects)) {
    options_.workTiles = std::move(workTiles);
    options_.tileSize = workTile;
  }
  std::vector<gp::Box3> shadeShare(const std::vector<gp::Box3>& needed, const Camera& camera) const override {
    // A frame's shading boxes span the whole slice; cut them into bricks so
    // that what this GP's tiles do not see is really skipped.
    constexpr std::int64_t B = 16;
    std::vector<gp::Box3> out;
    for (const gp::Box3& b : needed) {
      const gp::Box3 c = b.intersect({Index3(0), grid_.dims});
      for (std::int64_t k = c.lo.z; k < c.hi.z; k += B)
        for (std::int64_t j = c.lo.y; j < c.hi.y; j += B)
          for (std::int64_t i = c.lo.x; i < c.hi.x; i += B) {
            const gp::Box3 brick{Index3(i, j, k), glm::min(Index3(i, j, k) + Index3(B), c.hi)};
            if (visible(brick, camera)) out.push_back(brick);
          }
    }
    return out;
  }
  std::vector<gp::Box3> shadeAll(const Camera& camera) const override {
    // Bricks, so that what none of this GP's tiles sees is skipped.
    constexpr std::int64_t B = 32;
    const Index3 d = grid_.dims;
    std::vector<gp::Box3> seen;
    for (std::int64_t k = 0; k < d.z; k += B)
      for (std::int64_t j = 0; j < d.y; j += B)
        for (std::int64_t i = 0; i < d.x; i += B) {
          const gp::Box3 b{Index3(i, j, k), glm::min(Index3(i, j, k) + Index3(B), d)};
          if (visible(b, camera)) seen.push_back(b);
        }
    return seen;
  }
  // This GP shaded only what its tiles saw under the old view, so a new view
  // needs its bricks shaded anew.
  std::optional<gp::Box3> relightRegion() const override { return std::nullopt; }
  const gp::SamplerOptions& sampler() const override { return options_; }

private:
  Grid grid_;
  std::vector<TileRect> rects_;  // this GP's screen tiles
  gp::SamplerOptions options_;

  // Whether a sample in one of this GP's tiles can read a voxel of `b`.
  bool visible(const gp::Box3& b, const Camera& camera) const {
    const std::optional<gp::PixelBounds> f = gp::stencilFootprint(grid_, b, camera);
    if (!f) return true;  // reaches behind the eye: keep it
    const double px0 = f->x0, px1 = f->x1, py0 = f->y0, py1 = f->y1;
    for (const TileRect& r : rects_)
      if (px1 >= r.x0 && px0 < r.x0 + r.width && py1 >= r.y0 && py0 < r.y0 + r.height) return true;
    return false;
  }
};

class TilePartition final : public Partition {
public:
  TilePartition(const ParallelSettings& s, const RankLayout& layout, const Grid& grid, const TileGrid& tiles)
      : grid_(grid), tiles_(tiles), gps_(layout.gps), own_(s.ownership()) {}

  std::unique_ptr<gp::GpShare> share(int g) const override {
    std::vector<TileRect> rects;
    for (int i : tilesOwnedBy(g, tiles_.count(), gps_, own_)) rects.push_back(tiles_.rect(i));
    const std::vector<std::uint32_t> owners = workTileOwners(tiles_);
    std::vector<std::uint8_t> mask(owners.size(), 0);
    for (std::size_t w = 0; w < owners.size(); ++w)
      mask[w] = tileOwner(static_cast<int>(owners[w]), tiles_.count(), gps_, own_) == g;
    return std::make_unique<TileShare>(grid_, std::move(rects), std::move(mask), workTileSize(tiles_));
  }
  std::optional<gp::Box3> window(int) const override { return std::nullopt; }
  gp::Box3 volumePart(int g) const override { return g == 0 ? gp::Box3{Index3(0), grid_.dims} : gp::Box3{}; }
  bool placesFrames() const override { return false; }
  std::vector<int> gpsReached(const gp::WorldBox&) const override {
    std::vector<int> all(static_cast<std::size_t>(gps_));
    for (int g = 0; g < gps_; ++g) all[static_cast<std::size_t>(g)] = g;
    return all;
  }

private:
  Grid grid_;
  TileGrid tiles_;
  int gps_;
  TileOwnership own_;
};

}  // namespace

std::unique_ptr<Partition> makeTilePartition(const ParallelSettings& s, const RankLayout& layout, const Grid& grid,
                                             const TileGrid& tiles) {
  return std::make_unique<TilePartition>(s, layout, grid, tiles);
}

}  // namespace pp5::parallel
