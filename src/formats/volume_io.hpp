#pragma once
// 3D volumes on a Grid, read and written as MetaIO (.mha, .mhd+.raw) and NRRD
// (.nrrd), with spacing and origin so that 3D Slicer, ITK and VTK place them
// correctly (MetaIO Offset / NRRD space origin = centre of voxel 0; RAI/LPS
// conventions documented in docs/protocol.md).
#include <cstdint>
#include <string>
#include <vector>

#include "core/grid.hpp"

namespace pp5 {

enum class ScalarType : std::uint8_t { U8, U16, F32 };
int scalarBytes(ScalarType t);
const char* scalarName(ScalarType t);  // "uint8", "uint16", "float32"

struct Volume {
  Grid grid;
  ScalarType type = ScalarType::U8;
  std::vector<std::uint8_t> bytes;  // x fastest, little-endian

  void allocate(const Grid& g, ScalarType t);  // zero-filled; refuses grids that do not fit
  double value(std::size_t linearIndex) const;
  void setValue(std::size_t linearIndex, double v);  // clamps and rounds for integer types
  // The same volume in another voxel type (rounded and clamped by setValue).
  Volume as(ScalarType t) const;
  // Voxels [first, first + n) as as(U8) makes them, into out.
  void toU8(std::size_t first, std::size_t n, std::uint8_t* out) const;
};

struct VolumeHeader {
  Grid grid;
  ScalarType type = ScalarType::U8;
  int channels = 1;
  bool compressed = false;
};

// Header only.
VolumeHeader readVolumeHeader(const std::string& path);
// The header, checked as readVolume checks a volume before it reads it (the
// geometry, the data's size against the file), without reading the data or
// asking for its memory: `pp5echo info` for volumes of any size.
VolumeHeader checkVolumeFile(const std::string& path);
Volume readVolume(const std::string& path);
void writeVolume(const std::string& path, const Volume& v, bool compress = true);

}  // namespace pp5
