#pragma once
// The shading stage's output and the ray sampler's input: per voxel of the
// reconstruction grid, the shaded colour and opacity, premultiplied by the
// opacity (so trilinear interpolation of it does not bleed colour from
// transparent voxels), 8 bits per channel, x fastest like every volume.
#include <cstdint>
#include <vector>

#include "core/grid.hpp"

namespace pp5::gp {

struct ShadeVoxel {
  std::uint8_t r = 0, g = 0, b = 0, a = 0;  // premultiplied: r, g, b <= a
  bool operator==(const ShadeVoxel&) const = default;
};
static_assert(sizeof(ShadeVoxel) == 4);

class ShadeBuffer {
public:
  ShadeBuffer() = default;
  // All voxels transparent. The caller checks the memory (checkGridFits, 4 bytes per voxel).
  explicit ShadeBuffer(const Grid& g) : grid_(g), v_(g.voxelCount()) {}
  const Grid& grid() const { return grid_; }
  ShadeVoxel* data() { return v_.data(); }
  const ShadeVoxel* data() const { return v_.data(); }
  ShadeVoxel& at(std::size_t linearIndex) { return v_[linearIndex]; }
  const ShadeVoxel& at(std::size_t linearIndex) const { return v_[linearIndex]; }
  std::uint64_t memoryBytes() const { return v_.size() * sizeof(ShadeVoxel); }

private:
  Grid grid_;
  std::vector<ShadeVoxel> v_;
};

}  // namespace pp5::gp
