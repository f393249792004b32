#pragma once
// A regular 3D grid in mm. origin is the centre of voxel (0,0,0), as in MetaIO's
// Offset and NRRD's space origin; axes are aligned with the reference frame.
#include <cstddef>
#include <cstdint>
#include <string>

#include <glm/glm.hpp>

#include "core/transform.hpp"

namespace pp5 {

using Index3 = glm::i64vec3;

struct Grid {
  Vec3 origin{0.0};
  Vec3 spacing{1.0};
  Index3 dims{0};

  std::uint64_t voxelCount() const {
    return static_cast<std::uint64_t>(dims.x) * static_cast<std::uint64_t>(dims.y) * static_cast<std::uint64_t>(dims.z);
  }
  // Bytes needed for `voxelCount()` voxels of `bytesPerVoxel` each; saturates
  // instead of overflowing for absurd sizes.
  std::uint64_t memoryBytes(std::uint64_t bytesPerVoxel) const;
  Vec3 voxelToWorld(const Vec3& ijk) const { return origin + ijk * spacing; }
  Vec3 worldToVoxel(const Vec3& p) const { return (p - origin) / spacing; }
  // Bounding box of voxel centres.
  Vec3 minCorner() const { return origin; }
  Vec3 maxCorner() const { return origin + Vec3(dims - Index3(1)) * spacing; }
  std::size_t linear(std::int64_t i, std::int64_t j, std::int64_t k) const {
    return static_cast<std::size_t>((k * dims.y + j) * dims.x + i);
  }
  bool contains(std::int64_t i, std::int64_t j, std::int64_t k) const {
    return i >= 0 && j >= 0 && k >= 0 && i < dims.x && j < dims.y && k < dims.z;
  }
};

// InvariantError (naming both) unless the two grids are the same lattice:
// equal dims, origin and spacing, bit for bit.
void checkSameGrid(const Grid& a, const Grid& b);

// Memory a process may use for grids, in bytes: MemAvailable from /proc/meminfo
// (or sysconf as a fallback), or the override when > 0.
std::uint64_t availableMemoryBytes();

// Throws InputError ("<what>: grid of AxBxC voxels needs N GiB, but only M GiB
// is available") before anything is allocated, when the grid's spacing or dims
// are invalid or `bytesPerVoxel` per voxel would not fit in `limitBytes`
// (0 = availableMemoryBytes()).
void checkGridFits(const Grid& g, std::uint64_t bytesPerVoxel, const std::string& what,
                   std::uint64_t limitBytes = 0);

}  // namespace pp5
