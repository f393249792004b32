#include "core/tiles.hpp"

#include <algorithm>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5 {

TileGrid::TileGrid(int w, int h, int ts) : width(w), height(h), tileSize(ts) {
  if (w < 1 || h < 1 || ts < 1)
    throw InputError(fmt::format("a {}x{} pixel image cannot be cut into tiles of {} pixels: every size must be at "
                                 "least 1",
                                 w, h, ts));
}

TileRect TileGrid::rect(int tile) const {
  if (tile < 0 || tile >= count())
    throw InvariantError(fmt::format("tile {} is outside the image's tiles 0..{}", tile, count() - 1));
  const int c = tile % cols(), r = tile / cols();
  TileRect t;
  t.x0 = c * tileSize;
  t.y0 = r * tileSize;
  t.width = std::min(tileSize, width - t.x0);
  t.height = std::min(tileSize, height - t.y0);
  return t;
}

int TileGrid::tileOfPixel(std::uint32_t pixel) const {
  const auto w = static_cast<std::uint32_t>(width);
  if (width < 1 || height < 1 || tileSize < 1 || pixel / w >= static_cast<std::uint32_t>(height))
    throw InvariantError(fmt::format("pixel {} is outside the {}x{} image", pixel, width, height));
  const int x = static_cast<int>(pixel % w), y = static_cast<int>(pixel / w);
  return (y / tileSize) * cols() + x / tileSize;
}

std::vector<std::uint64_t> samplesPerTile(const TileGrid& tiles, std::span<const std::uint16_t> counts) {
  const std::size_t n = static_cast<std::size_t>(tiles.width) * static_cast<std::size_t>(tiles.height);
  if (counts.size() != n)
    throw InvariantError(fmt::format("{} sample counts given for a {}x{} image", counts.size(), tiles.width,
                                     tiles.height));
  std::vector<std::uint64_t> sums(static_cast<std::size_t>(tiles.count()), 0);
  const int cols = tiles.cols();
  for (int y = 0; y < tiles.height; ++y) {
    const std::uint16_t* row = counts.data() + static_cast<std::size_t>(y) * static_cast<std::size_t>(tiles.width);
    std::uint64_t* rowSums = sums.data() + static_cast<std::size_t>(y / tiles.tileSize) * static_cast<std::size_t>(cols);
    for (int c = 0; c < cols; ++c) {
      const int x0 = c * tiles.tileSize, x1 = std::min(tiles.width, x0 + tiles.tileSize);
      std::uint64_t s = 0;
      for (int x = x0; x < x1; ++x) s += row[x];
      rowSums[c] += s;
    }
  }
  return sums;
}

}  // namespace pp5
