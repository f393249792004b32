#include "formats/volume_io.hpp"

#include <algorithm>
#include <limits>
#include <memory>
#include <bit>
#include <cmath>
#include <cstring>

#include "core/error.hpp"
#include "formats/image_file.hpp"

namespace pp5 {

int scalarBytes(ScalarType t) {
  switch (t) {
    case ScalarType::U8: return 1;
    case ScalarType::U16: return 2;
    case ScalarType::F32: return 4;
  }
  return 1;
}

const char* scalarName(ScalarType t) {
  switch (t) {
    case ScalarType::U8: return "uint8";
    case ScalarType::U16: return "uint16";
    case ScalarType::F32: return "float32";
  }
  return "?";
}

void Volume::allocate(const Grid& g, ScalarType t) {
  checkGridFits(g, static_cast<std::uint64_t>(scalarBytes(t)), "volume");
  grid = g;
  type = t;
  bytes.assign(static_cast<std::size_t>(g.voxelCount()) * static_cast<std::size_t>(scalarBytes(t)), 0);
}

// Stored little-endian whatever the host, as the files are; assembled byte by
// byte so the code does not depend on the host's byte order.
Volume Volume::as(ScalarType t) const {
  if (t == type) return *this;
  Volume out;
  out.allocate(grid, t);
  const std::size_t n = grid.voxelCount();
  if (t == ScalarType::U8) {
    toU8(0, n, out.bytes.data());
    return out;
  }
  for (std::size_t i = 0; i < n; ++i) out.setValue(i, value(i));
  return out;
}

namespace {
// What an integer voxel holds of v: 0 for anything not above 0 (NaN too), hi
// at and above it, rounded between.
double clampRound(double x, double hi) {
  if (!(x > 0.0)) return 0.0;
  return x >= hi ? hi : std::round(x);
}
}  // namespace

void Volume::toU8(std::size_t first, std::size_t n, std::uint8_t* out) const {
  if (type == ScalarType::F32 && std::endian::native == std::endian::little) {
    for (std::size_t i = 0; i < n; ++i) {  // a tight loop: float voxels stored little-endian, as this machine's
      float f;
      std::memcpy(&f, bytes.data() + 4 * (first + i), 4);
      // clampRound's value without a call: a float plus one half is exact in
      // a double, so below 255 its truncation is std::round's rounding.
      const double x = f;
      out[i] = !(x > 0.0) ? 0 : x >= 255.0 ? 255 : static_cast<std::uint8_t>(static_cast<int>(x + 0.5));
    }
    return;
  }
  for (std::size_t i = 0; i < n; ++i) out[i] = static_cast<std::uint8_t>(clampRound(value(first + i), 255.0));
}

double Volume::value(std::size_t i) const {
  switch (type) {
    case ScalarType::U8: return bytes[i];
    case ScalarType::U16: return static_cast<double>(bytes[2 * i] | (bytes[2 * i + 1] << 8));
    case ScalarType::F32: {
      std::uint32_t u = 0;
      for (int b = 3; b >= 0; --b) u = (u << 8) | bytes[4 * i + static_cast<std::size_t>(b)];
      return static_cast<double>(std::bit_cast<float>(u));
    }
  }
  return 0.0;
}

void Volume::setValue(std::size_t i, double v) {
  switch (type) {
    case ScalarType::U8: bytes[i] = static_cast<std::uint8_t>(clampRound(v, 255.0)); break;
    case ScalarType::U16: {
      const auto u = static_cast<std::uint16_t>(clampRound(v, 65535.0));
      bytes[2 * i] = static_cast<std::uint8_t>(u & 0xff);
      bytes[2 * i + 1] = static_cast<std::uint8_t>(u >> 8);
      break;
    }
    case ScalarType::F32: {
      const auto u = std::bit_cast<std::uint32_t>(static_cast<float>(v));
      for (int b = 0; b < 4; ++b) bytes[4 * i + static_cast<std::size_t>(b)] = static_cast<std::uint8_t>(u >> (8 * b));
      break;
    }
  }
}

namespace {

VolumeHeader volumeHeaderFrom(const io::ImageHeader& h) {
  const char* sizeKey = h.format == SequenceFormat::MetaIO ? "DimSize" : "sizes";
  if (h.dims.size() < 2 || h.dims.size() > 3)
    inputError(h.path, "{} {}: a volume needs 3 dimensions", sizeKey, io::dimsText(h.dims));
  if (!h.axisAligned)
    inputError(h.path,
               "the volume's axes are rotated or flipped (TransformMatrix / space directions), "
               "which is not supported");
  VolumeHeader v;
  switch (*h.element) {
    case io::ElementType::U8: v.type = ScalarType::U8; break;
    case io::ElementType::U16: v.type = ScalarType::U16; break;
    case io::ElementType::F32: v.type = ScalarType::F32; break;
    default:
      inputError(h.path, "pixel type {} is not supported for volumes (uint8, uint16 or float32)",
                 io::elementName(*h.element));
  }
  v.grid.dims = Index3(h.dims[0], h.dims[1], h.dims.size() == 3 ? h.dims[2] : 1);
  v.grid.spacing = h.spacing;
  v.grid.origin = h.origin;
  v.channels = h.channels;
  v.compressed = h.compressed;
  return v;
}

void swapElements(std::vector<std::uint8_t>& bytes, std::size_t elementSize) {
  for (std::size_t i = 0; i + elementSize <= bytes.size(); i += elementSize)
    std::reverse(bytes.begin() + static_cast<std::ptrdiff_t>(i),
                 bytes.begin() + static_cast<std::ptrdiff_t>(i + elementSize));
}

}  // namespace

VolumeHeader readVolumeHeader(const std::string& path) { return volumeHeaderFrom(io::readImageHeader(path)); }

namespace {
// The volume's data, opened after its size is checked against the file, and
// its geometry checked (positive, finite spacing; a finite origin; no empty
// axis); with `memoryLimit` (0: the machine's) for the grid's bytes.
std::unique_ptr<io::DataReader> openVolumeData(const io::ImageHeader& h, const VolumeHeader& vh,
                                               std::uint64_t memoryLimit) {
  const auto total = io::dataBytes(h);
  if (!total) inputError(h.path, "the volume's size {} is too large", io::dimsText(h.dims));
  auto data = std::make_unique<io::DataReader>(h, *total, 1, "volume");
  checkGridFits(vh.grid, static_cast<std::uint64_t>(scalarBytes(vh.type) * vh.channels), h.path, memoryLimit);
  return data;
}
}  // namespace

VolumeHeader checkVolumeFile(const std::string& path) {
  const io::ImageHeader h = io::readImageHeader(path);
  const VolumeHeader vh = volumeHeaderFrom(h);
  (void)openVolumeData(h, vh, std::numeric_limits<std::uint64_t>::max());
  return vh;
}

Volume readVolume(const std::string& path) {
  const io::ImageHeader h = io::readImageHeader(path);
  const VolumeHeader vh = volumeHeaderFrom(h);
  if (vh.channels != 1) inputError(path, "{} channels per voxel: multi-channel volumes are not supported", vh.channels);
  const auto elementSize = static_cast<std::uint64_t>(scalarBytes(vh.type));
  // Sizes are checked against the data before anything large is allocated.
  const std::unique_ptr<io::DataReader> data = openVolumeData(h, vh, 0);
  Volume v;
  v.allocate(vh.grid, vh.type);
  data->read(v.bytes.data(), 0);
  data->expectEnd();
  if (h.bigEndian && elementSize > 1) swapElements(v.bytes, elementSize);
  return v;
}

void writeVolume(const std::string& path, const Volume& v, bool compress) {
  PP5_CHECK_EQ(v.bytes.size(), v.grid.voxelCount() * static_cast<std::uint64_t>(scalarBytes(v.type)));
  io::ImageFileWriter file(path, compress, 6);
  file.writeData(v.bytes.data(), v.bytes.size());
  io::ImageHeader h;
  h.dims = {v.grid.dims.x, v.grid.dims.y, v.grid.dims.z};
  h.element = v.type == ScalarType::U8    ? io::ElementType::U8
              : v.type == ScalarType::U16 ? io::ElementType::U16
                                          : io::ElementType::F32;
  h.spacing = v.grid.spacing;
  h.origin = v.grid.origin;
  h.kinds = {"domain", "domain", "domain"};
  file.finish(std::move(h));
}

}  // namespace pp5
