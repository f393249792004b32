#include "igtl/igtl_wire.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::igtl::wire {

namespace {

[[noreturn]] void imageError(const std::string& device, const std::string& what) {
  throw InputError(fmt::format("OpenIGTLink IMAGE '{}': {}", device, what));
}

// An IMAGE's voxel-block centre in voxel indices: (size - 1) / 2.
Vec3 centreIndex(const codec::Image& im) {
  return 0.5 * Vec3(im.size[0] - 1, im.size[1] - 1, im.size[2] - 1);
}

void rowMajor(const Mat4& m, double out[16]) {
  for (int row = 0; row < 4; ++row)
    for (int col = 0; col < 4; ++col) out[row * 4 + col] = m[col][row];
}

}  // namespace

std::string transformName(const std::string& device) {
  static const std::string suffix = "Transform";
  if (device.size() > suffix.size() && device.compare(device.size() - suffix.size(), suffix.size(), suffix) == 0)
    return device.substr(0, device.size() - suffix.size());
  return device;
}

std::string imageFrameName(const std::string& device) {
  static const std::string prefix = "Image_";
  if (device.size() > prefix.size() && device.compare(0, prefix.size(), prefix) == 0)
    return device.substr(prefix.size());
  return {};
}

Mat4 transformOf(const std::string& content) {
  double m[16];
  codec::readTransform(content, m);
  Mat4 r(1.0);
  for (int row = 0; row < 4; ++row)
    for (int col = 0; col < 4; ++col) r[col][row] = m[row * 4 + col];
  return r;
}

std::string packTransform(const std::string& device, const Mat4& m, double timeS) {
  double rm[16];
  rowMajor(m, rm);
  codec::Body b;
  b.content = codec::transformContent(rm);
  return codec::pack(1, "TRANSFORM", device, encodeTime(std::max(0.0, timeS)), b);
}

void imageToFrame(const codec::Image& im, const std::string& content, const std::string& device, WireTime time,
                  Frame& f) {
  // Bounds first: the sizes below are products of these.
  for (int i = 0; i < 3; ++i)
    if (im.size[i] <= 0)
      imageError(device, fmt::format("image size {}x{}x{} is out of range", im.size[0], im.size[1], im.size[2]));
  if (im.size[2] != 1)
    imageError(device, fmt::format("a 3D image ({}x{}x{}) is not a 2D frame", im.size[0], im.size[1], im.size[2]));
  for (int i = 0; i < 3; ++i)
    if (im.subSize[i] != im.size[i] || im.subOffset[i] != 0)
      imageError(device, "carries part of an image (a sub-volume); only whole images are supported");
  if (im.components != 1)
    imageError(device, fmt::format("has {} components per pixel; only 1 is supported", im.components));
  PixelType type;
  switch (im.scalarType) {
    case codec::kUint8: type = PixelType::U8; break;
    case codec::kUint16: type = PixelType::U16; break;
    default: imageError(device, fmt::format("scalar type {} is not supported (uint8 = 3 and uint16 = 5 are)", im.scalarType));
  }
  if (type == PixelType::U16 && im.endian != codec::kBigEndian && im.endian != codec::kLittleEndian)
    imageError(device, fmt::format("unknown byte order {}", im.endian));
  f.allocate(im.size[0], im.size[1], type);
  // The content must hold the pixels its header promises; a short one would
  // be read past its end.
  if (content.size() < im.dataOffset + f.byteSize())
    imageError(device, fmt::format("body of {} bytes is too short for {} bytes of pixels", content.size(), f.byteSize()));
  // IMAGE stores i (columns) fastest, then j (rows): the Frame's row-major order.
  std::memcpy(f.pixels.data(), content.data() + im.dataOffset, f.byteSize());
  if (type == PixelType::U16 && im.endian == codec::kBigEndian)
    for (std::size_t i = 0; i + 1 < f.pixels.size(); i += 2) std::swap(f.pixels[i], f.pixels[i + 1]);
  f.timestamp = decodeTime(time);
  f.imageValid = true;
}

Mat4 imagePixelToFrame(const codec::Image& im) {
  Mat4 r(1.0);
  for (int col = 0; col < 4; ++col)
    for (int row = 0; row < 3; ++row) r[col][row] = static_cast<double>(im.matrix[col * 3 + row]);
  // The translation is the centre of the voxels: pixel 0 lies half the block before it.
  const Vec3 centre(r[3]);
  r[3] = Vec4(centre - glm::dmat3(r) * centreIndex(im), 1.0);
  return r;
}

void setImageGeometry(codec::Image& im, const Mat4& pixelToFrame) {
  for (int col = 0; col < 3; ++col) {
    const Vec3 axis(pixelToFrame[col]);
    const double len = glm::length(axis);
    if (!(len > 0.0) || !std::isfinite(len))
      throw InputError(fmt::format("image matrix column {} has length {}; it cannot be sent as an IMAGE", col, len));
    for (int row = 0; row < 3; ++row) im.matrix[col * 3 + row] = static_cast<float>(axis[row]);
  }
  const Vec4 centre = pixelToFrame * Vec4(centreIndex(im), 1.0);
  for (int row = 0; row < 3; ++row) im.matrix[9 + row] = static_cast<float>(centre[row]);
}

namespace {

std::string packImage(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                      const Mat4& pixelToFrame, const Index3& offset, const Index3& size, WireTime time,
                      int components) {
  codec::Image im;
  im.components = components;
  im.scalarType = codec::kUint8;
  for (int a = 0; a < 3; ++a) {
    if (dims[a] < 1 || dims[a] > 0xffff) imageError(device, fmt::format("a side of {} voxels (at most 65535)", dims[a]));
    im.size[a] = static_cast<int>(dims[a]);
    im.subOffset[a] = static_cast<int>(offset[a]);
    im.subSize[a] = static_cast<int>(size[a]);
  }
  setImageGeometry(im, pixelToFrame);
  const std::size_t c = static_cast<std::size_t>(components), row = static_cast<std::size_t>(size.x) * c;
  std::string data(row * static_cast<std::size_t>(size.y * size.z), '\0');
  char* out = data.data();
  for (std::int64_t z = 0; z < size.z; ++z)
    for (std::int64_t y = 0; y < size.y; ++y) {
      const std::size_t from = static_cast<std::size_t>(((offset.z + z) * dims.y + offset.y + y) * dims.x + offset.x) * c;
      std::memcpy(out, voxels + from, row);
      out += row;
    }
  codec::Body b;
  b.content = codec::imageContent(im, reinterpret_cast<const std::uint8_t*>(data.data()), data.size());
  return codec::pack(1, "IMAGE", device, time, b);
}

}  // namespace

std::string packCentredImage(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                             const Mat4& pixelToFrame, double timeS, int components) {
  return packImage(device, dims, voxels, pixelToFrame, Index3(0), dims, encodeTime(std::max(0.0, timeS)), components);
}

std::string packSubVolume(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                          const Mat4& pixelToFrame, const Index3& offset, const Index3& size, double timeS) {
  for (int a = 0; a < 3; ++a)
    if (offset[a] < 0 || size[a] <= 0 || offset[a] + size[a] > dims[a])
      throw InvariantError("packSubVolume: the box is not inside the volume");
  return packImage(device, dims, voxels, pixelToFrame, offset, size, encodeTime(std::max(0.0, timeS)), 1);
}

std::string packFrame(const std::string& device, const Frame& f, const Mat4& pixelToFrame, bool bigEndian,
                      WireTime time) {
  codec::Image im;
  im.scalarType = f.pixelType == PixelType::U8 ? codec::kUint8 : codec::kUint16;
  im.endian = bigEndian ? codec::kBigEndian : codec::kLittleEndian;
  im.size[0] = im.subSize[0] = f.width;
  im.size[1] = im.subSize[1] = f.height;
  setImageGeometry(im, pixelToFrame);
  std::string px(reinterpret_cast<const char*>(f.pixels.data()), f.byteSize());
  if (bigEndian && f.pixelType == PixelType::U16)  // Frame pixels are little-endian
    for (std::size_t i = 0; i + 1 < px.size(); i += 2) std::swap(px[i], px[i + 1]);
  codec::Body b;
  b.content = codec::imageContent(im, reinterpret_cast<const std::uint8_t*>(px.data()), px.size());
  return codec::pack(1, "IMAGE", device, time, b);
}

}  // namespace pp5::igtl::wire
