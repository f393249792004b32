#include "igtl/igtl_wire.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::igtl::wire {

namespace {
constexpr double kFracScale = 4294967296.0;  // 2^32

[[noreturn]] void imageError(const std::string& device, const std::string& what) {
  throw InputError(fmt::format("OpenIGTLink IMAGE '{}': {}", device, what));
}
}  // namespace

WireTime encodeTime(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0.0 || seconds >= kFracScale)
    throw InputError(fmt::format("timestamp {} s cannot be sent over OpenIGTLink (0 <= t < 2^32 s)", seconds));
  double whole = std::floor(seconds);
  double frac = std::round((seconds - whole) * kFracScale);
  if (frac >= kFracScale) {  // rounded up to the next second
    whole += 1.0;
    frac = 0.0;
  }
  return {static_cast<std::uint32_t>(whole), static_cast<std::uint32_t>(frac)};
}

double decodeTime(WireTime t) { return static_cast<double>(t.sec) + static_cast<double>(t.frac) / kFracScale; }

double messageTime(::igtl::MessageBase& m) {
  unsigned int sec = 0, frac = 0;
  m.GetTimeStamp(&sec, &frac);
  return decodeTime({sec, frac});
}

Mat4 toMat4(const ::igtl::Matrix4x4& m) {
  Mat4 r(1.0);
  for (int row = 0; row < 4; ++row)
    for (int col = 0; col < 4; ++col) r[col][row] = static_cast<double>(m[row][col]);
  return r;
}

void toIgtl(const Mat4& m, ::igtl::Matrix4x4& out) {
  for (int row = 0; row < 4; ++row)
    for (int col = 0; col < 4; ++col) out[row][col] = static_cast<float>(m[col][row]);
}

Mat4 roundToFloat(const Mat4& m) {
  ::igtl::Matrix4x4 f;
  toIgtl(m, f);
  return toMat4(f);
}

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

void imageToFrame(::igtl::ImageMessage& img, Frame& f) {
  const std::string device = img.GetDeviceName();
  int dims[3], sub[3], off[3];
  img.GetDimensions(dims);
  img.GetSubVolume(sub, off);
  // Bounds first: the sizes below are products of these.
  constexpr int kMaxSide = 1 << 15;
  for (int i = 0; i < 3; ++i)
    if (dims[i] <= 0 || dims[i] > kMaxSide)
      imageError(device, fmt::format("image size {}x{}x{} is out of range", dims[0], dims[1], dims[2]));
  if (dims[2] != 1)
    imageError(device, fmt::format("a 3D image ({}x{}x{}) is not a 2D frame", dims[0], dims[1], dims[2]));
  for (int i = 0; i < 3; ++i)
    if (sub[i] != dims[i] || off[i] != 0)
      imageError(device, "carries part of an image (a sub-volume); only whole images are supported");
  if (img.GetNumComponents() != 1)
    imageError(device, fmt::format("has {} components per pixel; only 1 is supported", img.GetNumComponents()));

  PixelType type;
  switch (img.GetScalarType()) {
    case ::igtl::ImageMessage::TYPE_UINT8: type = PixelType::U8; break;
    case ::igtl::ImageMessage::TYPE_UINT16: type = PixelType::U16; break;
    default:
      imageError(device, fmt::format("scalar type {} is not supported (uint8 = 3 and uint16 = 5 are)",
                                     img.GetScalarType()));
  }
  const int endian = img.GetEndian();
  if (type == PixelType::U16 && endian != ::igtl::ImageMessage::ENDIAN_BIG &&
      endian != ::igtl::ImageMessage::ENDIAN_LITTLE)
    imageError(device, fmt::format("unknown byte order {}", endian));

  f.allocate(dims[0], dims[1], type);
  // The body must hold the pixels its header promises; a short one would be
  // read past its end.
  const std::size_t have = static_cast<std::size_t>(img.GetPackBodySize());
  if (have < IGTL_IMAGE_HEADER_SIZE + f.byteSize())
    imageError(device, fmt::format("body of {} bytes is too short for {} bytes of pixels", have, f.byteSize()));
  // IMAGE stores i (columns) fastest, then j (rows): the Frame's row-major order.
  std::memcpy(f.pixels.data(), img.GetScalarPointer(), f.byteSize());
  if (type == PixelType::U16 && endian == ::igtl::ImageMessage::ENDIAN_BIG)
    for (std::size_t i = 0; i + 1 < f.pixels.size(); i += 2) std::swap(f.pixels[i], f.pixels[i + 1]);
  f.timestamp = messageTime(img);
  f.imageValid = true;
}

namespace {
// An IMAGE's voxel-block centre in voxel indices: (dims - 1) / 2.
Vec3 centreIndex(::igtl::ImageMessage& img) {
  int dims[3];
  img.GetDimensions(dims);
  return 0.5 * Vec3(dims[0] - 1, dims[1] - 1, dims[2] - 1);
}
}  // namespace

Mat4 imagePixelToFrame(::igtl::ImageMessage& img) {
  ::igtl::Matrix4x4 m;
  img.GetMatrix(m);
  float spacing[3];
  img.GetSpacing(spacing);
  Mat4 r = toMat4(m);
  for (int col = 0; col < 3; ++col) r[col] *= static_cast<double>(spacing[col]);
  r[0][3] = r[1][3] = r[2][3] = 0.0;
  r[3][3] = 1.0;
  // The matrix's translation is the centre of the voxels: pixel 0 lies half
  // the block before it.
  const Vec3 centre(r[3]);
  r[3] = Vec4(centre - glm::dmat3(r) * centreIndex(img), 1.0);
  return r;
}

void setImageGeometry(::igtl::ImageMessage& img, const Mat4& pixelToFrame) {
  ::igtl::Matrix4x4 m;
  float spacing[3];
  for (int col = 0; col < 3; ++col) {
    const Vec3 axis(pixelToFrame[col]);
    const double len = glm::length(axis);
    if (!(len > 0.0) || !std::isfinite(len))
      throw InputError(fmt::format("image matrix column {} has length {}; it cannot be sent as an IMAGE", col, len));
    spacing[col] = static_cast<float>(len);
    for (int row = 0; row < 3; ++row) m[row][col] = static_cast<float>(axis[row] / len);
    m[3][col] = 0.0f;
  }
  const Vec4 centre = pixelToFrame * Vec4(centreIndex(img), 1.0);
  for (int row = 0; row < 3; ++row) m[row][3] = static_cast<float>(centre[row]);
  m[3][3] = 1.0f;
  img.SetSpacing(spacing);
  img.SetMatrix(m);
}

namespace {

std::string packImage(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                      const Mat4& pixelToFrame, const Index3& offset, const Index3& size, double timeS,
                      int components) {
  auto img = ::igtl::ImageMessage::New();
  img->SetDeviceName(device.substr(0, kMaxDeviceName).c_str());
  img->SetDimensions(static_cast<int>(dims.x), static_cast<int>(dims.y), static_cast<int>(dims.z));
  img->SetSubVolume(static_cast<int>(size.x), static_cast<int>(size.y), static_cast<int>(size.z),
                    static_cast<int>(offset.x), static_cast<int>(offset.y), static_cast<int>(offset.z));
  img->SetNumComponents(components);
  img->SetScalarType(::igtl::ImageMessage::TYPE_UINT8);
  img->SetEndian(::igtl::ImageMessage::ENDIAN_LITTLE);
  setImageGeometry(*img, pixelToFrame);
  img->AllocateScalars();
  auto* out = static_cast<std::uint8_t*>(img->GetScalarPointer());
  const std::size_t c = static_cast<std::size_t>(components), row = static_cast<std::size_t>(size.x) * c;
  for (std::int64_t z = 0; z < size.z; ++z)
    for (std::int64_t y = 0; y < size.y; ++y) {
      const std::size_t from = static_cast<std::size_t>(((offset.z + z) * dims.y + offset.y + y) * dims.x + offset.x) * c;
      std::memcpy(out, voxels + from, row);
      out += row;
    }
  const WireTime t = encodeTime(std::max(0.0, timeS));
  img->SetTimeStamp(t.sec, t.frac);
  img->Pack();
  return {static_cast<const char*>(img->GetPackPointer()), static_cast<std::size_t>(img->GetPackSize())};
}

}  // namespace

std::string packCentredImage(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                             const Mat4& pixelToFrame, double timeS, int components) {
  return packImage(device, dims, voxels, pixelToFrame, Index3(0), dims, timeS, components);
}

std::string packSubVolume(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                          const Mat4& pixelToFrame, const Index3& offset, const Index3& size, double timeS) {
  for (int a = 0; a < 3; ++a)
    if (offset[a] < 0 || size[a] <= 0 || offset[a] + size[a] > dims[a])
      throw InvariantError("packSubVolume: the box is not inside the volume");
  return packImage(device, dims, voxels, pixelToFrame, offset, size, timeS, 1);
}

}  // namespace pp5::igtl::wire
