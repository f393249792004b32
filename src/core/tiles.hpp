#pragma once
// The screen's geometry as the ranks share it: a tile rectangle, the image cut
// into square tiles, and how many lattice samples each tile holds. The PPs'
// caches, the GPs' sample routing and the schedules all read it.
#include <cstdint>
#include <span>
#include <vector>

namespace pp5 {

// A screen rectangle in pixels; x0, y0 in the whole image.
struct TileRect {
  int x0 = 0, y0 = 0, width = 0, height = 0;
  bool empty() const { return width <= 0 || height <= 0; }
};

// The image cut into tiles of tileSize x tileSize pixels, row-major, the last
// column and row cut short.
struct TileGrid {
  int width = 0, height = 0, tileSize = 128;

  TileGrid() = default;
  TileGrid(int width, int height, int tileSize);  // InputError for sizes < 1
  int cols() const { return (width + tileSize - 1) / tileSize; }
  int rows() const { return (height + tileSize - 1) / tileSize; }
  int count() const { return cols() * rows(); }
  TileRect rect(int tile) const;
  int tileOfPixel(std::uint32_t pixel) const;  // pixel = y * width + x
};

// The lattice samples of each tile: the sum of its pixels' sample counts
// (SampleLattice::counts(), row-major over the image), the size of its ray cache.
std::vector<std::uint64_t> samplesPerTile(const TileGrid& tiles, std::span<const std::uint16_t> counts);

}  // namespace pp5
