#include "pipeline/partition.hpp"

#include <numeric>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::parallel {

std::unique_ptr<Partition> makePartition(const ParallelSettings& s, const RankLayout& layout, const Grid& grid,
                                         const gp::ReconSettings& recon, const TileGrid& tiles) {
  if (s.slab()) return makeSlabPartition(s, layout, grid, recon, tiles);
  return makeTilePartition(s, layout, grid, tiles);
}

int workTileSize(const TileGrid& tiles) { return std::gcd(32, tiles.tileSize); }

std::vector<std::uint32_t> workTileOwners(const TileGrid& tiles) {
  const int w = workTileSize(tiles);
  const int cols = (tiles.width + w - 1) / w, rows = (tiles.height + w - 1) / w;
  std::vector<std::uint32_t> out(static_cast<std::size_t>(cols) * static_cast<std::size_t>(rows));
  for (int wy = 0; wy < rows; ++wy)
    for (int wx = 0; wx < cols; ++wx)
      out[static_cast<std::size_t>(wy * cols + wx)] =
          static_cast<std::uint32_t>(tiles.tileOfPixel(static_cast<std::uint32_t>(wy * w * tiles.width + wx * w)));
  return out;
}

}  // namespace pp5::parallel
