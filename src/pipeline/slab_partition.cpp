// The slab (object-space) partitioning: GP g owns a box of the grid's cells
// (SlabLayout), reconstructs the voxels of its window (its cells' voxels and
// ghost layers), shades the voxels its cells' samples read and samples only
// the lattice points of its cells. The host sends a frame's pixels only to
// the GPs whose reconstruction the frame (and the fill-in before it) can
// reach; the others get its pose, so that their fill-in and motion state
// advance as the whole grid's would.
#include "reconstruction/kernels.hpp"
#include "pipeline/partition.hpp"

namespace pp5::parallel {

namespace {

class SlabShare final : public gp::GpShare {
public:
  SlabShare(const gp::Box3& shadeRegion, const gp::Box3& ownedCells, int workTile) : region_(shadeRegion) {
    options_.ownedCells = ownedCells;
    options_.tileSize = workTile;
  }
  std::vector<gp::Box3> shadeShare(const std::vector<gp::Box3>& needed, const Camera&) const override {
    std::vector<gp::Box3> out;
    for (const gp::Box3& b : needed) {
      const gp::Box3 c = b.intersect(region_);
      if (!c.empty()) out.push_back(c);
    }
    return out;
  }
  std::vector<gp::Box3> shadeAll(const Camera&) const override {
    if (region_.empty()) return {};
    return {region_};
  }
  std::optional<gp::Box3> relightRegion() const override { return region_; }
  std::optional<gp::Box3> shadeRegion() const override { return region_; }
  const gp::SamplerOptions& sampler() const override { return options_; }

private:
  gp::Box3 region_;  // the voxels its cells' samples read
  gp::SamplerOptions options_;
};

class SlabPartition final : public Partition {
public:
  SlabPartition(const ParallelSettings& s, const RankLayout& layout, const Grid& grid, const gp::ReconSettings& recon,
                const TileGrid& tiles)
      : grid_(grid),
        slabs_(grid, layout.gps, s.split()),
        ghost_(s.ghostVoxels),
        workTile_(workTileSize(tiles)),
        // The pose-only frames rest on the slice's reach (gp::frameReach).
        places_(gp::kernelFor(recon.method).windowed) {
    // What each GP's reconstruction depends on, once for the run.
    for (int g = 0; g < layout.gps; ++g) reaches_.push_back(slabs_.reach(g, ghost_, recon));
  }

  std::unique_ptr<gp::GpShare> share(int g) const override {
    const gp::Box3& owned = slabs_.ownedCells(g);
    gp::Box3 region;
    if (!owned.empty()) region = gp::Box3{owned.lo, owned.hi + Index3(1)}.intersect({Index3(0), grid_.dims});
    return std::make_unique<SlabShare>(region, owned, workTile_);
  }
  std::optional<gp::Box3> window(int g) const override {
    if (slabs_.ownedCells(g).empty()) return gp::Box3{};
    return slabs_.window(g, ghost_);
  }
  gp::Box3 volumePart(int g) const override {
    // Cells [lo, hi) own voxels [lo, hi); the grid's last voxel plane goes
    // with the last cell.
    gp::Box3 box = slabs_.ownedCells(g);
    if (box.empty()) return {};
    for (int a = 0; a < 3; ++a)
      if (box.hi[a] == grid_.dims[a] - 1) box.hi[a] = grid_.dims[a];
    return box;
  }
  bool placesFrames() const override { return places_; }
  std::vector<int> gpsReached(const gp::WorldBox& reach) const override {
    return gpsTouched(grid_, reaches_, reach);
  }

private:
  Grid grid_;
  SlabLayout slabs_;
  int ghost_;
  std::vector<gp::Box3> reaches_;  // per GP: the voxels its reconstruction depends on
  int workTile_;
  bool places_;
};

}  // namespace

std::unique_ptr<Partition> makeSlabPartition(const ParallelSettings& s, const RankLayout& layout, const Grid& grid,
                                             const gp::ReconSettings& recon, const TileGrid& tiles) {
  return std::make_unique<SlabPartition>(s, layout, grid, recon, tiles);
}

}  // namespace pp5::parallel
