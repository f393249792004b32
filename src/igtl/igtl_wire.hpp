#pragma once
// Conversions between OpenIGTLink messages and pp5 Frames. The client uses them
// to decode, and the test server decodes its own packed messages with them, so
// that what the server records as sent is what any client receives, bit for bit.
// Internal to src/igtl: it pulls in the OpenIGTLink headers.
#include <cstdint>
#include <string>

#include <igtlImageMessage.h>
#include <igtlTransformMessage.h>
#include <igtl_image.h>
#include <igtl_transform.h>

#include "core/frame.hpp"
#include "core/grid.hpp"
#include "core/transform.hpp"
#include "igtl/igtl_protocol.hpp"

namespace pp5::igtl::wire {

// The header's timestamp: whole seconds and a 32-bit binary fraction. Encoding
// rounds to the nearest 2^-32 s; negative or too-large times are an InputError.
struct WireTime {
  std::uint32_t sec = 0;
  std::uint32_t frac = 0;
};
WireTime encodeTime(double seconds);
double decodeTime(WireTime t);
double messageTime(::igtl::MessageBase& m);

// OpenIGTLink matrices are float32, row-major (m[row][col]); GLM is column-major
// double. float -> double is exact; double -> float rounds to nearest.
Mat4 toMat4(const ::igtl::Matrix4x4& m);
void toIgtl(const Mat4& m, ::igtl::Matrix4x4& out);
// What a matrix becomes after a trip through a TRANSFORM message.
Mat4 roundToFloat(const Mat4& m);

// "ProbeToTrackerTransform" -> "ProbeToTracker"; other names unchanged.
std::string transformName(const std::string& device);
// PLUS names an image by the frame it is given in: "Image_Reference" ->
// "Reference". Empty for any other name (its matrix is then not a pose).
std::string imageFrameName(const std::string& device);
constexpr std::size_t kMaxDeviceName = kDeviceNameLength;

// Size, pixel type, pixels (u16 little-endian) and timestamp of an unpacked
// IMAGE into f. InputError naming the device when a Frame cannot hold it.
void imageToFrame(::igtl::ImageMessage& img, Frame& f);
// Pixel indices -> mm in the image's frame, from the IMAGE's matrix, spacing
// and dimensions: the rotation times diag(spacing), and the matrix's
// translation taken as OpenIGTLink (and Slicer, and PlusServer) define it,
// the centre of the voxel block, at index (dims - 1) / 2.
Mat4 imagePixelToFrame(::igtl::ImageMessage& img);
// The inverse for a sender, after SetDimensions: spacing = the column lengths
// of m's 3x3 part, rotation = the columns divided by them, translation = where
// m puts the voxels' centre. InputError for a zero column.
void setImageGeometry(::igtl::ImageMessage& img, const Mat4& pixelToFrame);

// A packed 3D IMAGE of `dims` uint8 voxels (x fastest) whose voxel (i, j, k)
// lies at pixelToFrame * (i, j, k, 1): the matrix's translation is the
// centre of the voxel block, as OpenIGTLink defines an IMAGE's origin (the
// voxels' centre at (dims - 1) / 2), so that Slicer places it right. A 2D
// image is dims.z = 1; `components` bytes a voxel (3: RGB).
std::string packCentredImage(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                             const Mat4& pixelToFrame, double timeS, int components = 1);
// The box of `size` voxels at `offset` of that uint8 volume (`voxels` the
// whole volume's) as an IMAGE sub-volume: dimensions and matrix are the whole
// volume's, the data the box's, x fastest.
std::string packSubVolume(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                          const Mat4& pixelToFrame, const Index3& offset, const Index3& size, double timeS);

}  // namespace pp5::igtl::wire
