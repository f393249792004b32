#pragma once
// The GP partitionings, the subject of the benchmarks (design brief, "Two GP
// partitionings"): two implementations of one interface, one file each.
//  - slab_partition: object space. Each GP owns a box of the grid's cells
//    (SlabLayout) and keeps exact only the voxels its cells' samples read;
//    the host sends a frame's pixels only to the GPs the frame can reach.
//  - tile_partition: screen space. Every GP reconstructs the whole grid and
//    shades and samples only what its own screen tiles see.
// The rank loops ask the partition, never which one it is.
#include <memory>
#include <optional>
#include <vector>

#include "core/grid.hpp"
#include "core/tiles.hpp"
#include "rendering/dbuffer.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/gp_update.hpp"
#include "reconstruction/reconstruction.hpp"
#include "pipeline/parallel_settings.hpp"
#include "pipeline/schedule.hpp"

namespace pp5::parallel {

class Partition {
public:
  virtual ~Partition() = default;
  // GP g's share of the shading and sampling, for a gp::GpUpdate.
  virtual std::unique_ptr<gp::GpShare> share(int g) const = 0;
  // The voxels GP g's reconstruction must keep exact; nullopt: the whole grid.
  virtual std::optional<gp::Box3> window(int g) const = 0;
  // The part of the reconstructed volume GP g sends to the host: the parts
  // are disjoint and cover the grid.
  virtual gp::Box3 volumePart(int g) const = 0;
  // Whether a frame's pixels go only to the GPs it reaches (gpsReached),
  // the others getting its pose alone.
  virtual bool placesFrames() const = 0;
  // The GPs whose reconstruction a world box (gp::frameReach,
  // gp::fillInReach) can change, ascending.
  virtual std::vector<int> gpsReached(const gp::WorldBox& reach) const = 0;
};

// The partition `s.gpPartition` names, for this layout, grid and image.
std::unique_ptr<Partition> makePartition(const ParallelSettings& s, const RankLayout& layout, const Grid& grid,
                                         const gp::ReconSettings& recon, const TileGrid& tiles);

// The sampler's work tiles: squares of gcd(32, tile size) pixels, so that
// each lies in one screen tile, and the screen tile of each (row-major over
// the image's work tiles).
int workTileSize(const TileGrid& tiles);
std::vector<std::uint32_t> workTileOwners(const TileGrid& tiles);

std::unique_ptr<Partition> makeSlabPartition(const ParallelSettings& s, const RankLayout& layout, const Grid& grid,
                                             const gp::ReconSettings& recon, const TileGrid& tiles);
std::unique_ptr<Partition> makeTilePartition(const ParallelSettings& s, const RankLayout& layout, const Grid& grid,
                                             const TileGrid& tiles);

}  // namespace pp5::parallel
