#pragma once
// Conversions between OpenIGTLink messages (igtl/igtl_codec.hpp) and pp5's
// Frames and matrices. The client decodes with them, and the test server
// decodes its own packed messages with them, so that what the server records
// as sent is what any client receives, bit for bit. Internal to src/igtl.
#include <cstdint>
#include <string>

#include "core/frame.hpp"
#include "core/grid.hpp"
#include "core/transform.hpp"
#include "igtl/igtl_codec.hpp"
#include "igtl/igtl_protocol.hpp"

namespace pp5::igtl::wire {

using codec::decodeTime;
using codec::encodeTime;
using codec::WireTime;
constexpr std::size_t kMaxDeviceName = kDeviceNameLength;

// "ProbeToTrackerTransform" -> "ProbeToTracker"; other names unchanged.
std::string transformName(const std::string& device);
// PLUS names an image by the frame it is given in: "Image_Reference" ->
// "Reference". Empty for any other name (its matrix is then not a pose).
std::string imageFrameName(const std::string& device);

// A TRANSFORM's matrix (float32 on the wire: float -> double is exact).
Mat4 transformOf(const std::string& content);
// A packed TRANSFORM (the matrix rounded to float32).
std::string packTransform(const std::string& device, const Mat4& m, double timeS);

// Size, pixel type, pixels (u16 little-endian) and timestamp of an IMAGE into
// f. InputError naming the device when a Frame cannot hold it (3D, a
// sub-volume, RGB, another scalar type, fewer voxels than its size).
void imageToFrame(const codec::Image& im, const std::string& content, const std::string& device, WireTime time,
                  Frame& f);
// Pixel indices -> mm in the image's frame, as OpenIGTLink (and Slicer, and
// PlusServer) define an IMAGE's geometry: the matrix's columns are the voxel
// axes times the spacing, and its translation is the centre of the voxel
// block, at index (size - 1) / 2.
Mat4 imagePixelToFrame(const codec::Image& im);
// The inverse for a sender, once im.size is set: the axes from m's columns,
// the translation where m puts the voxels' centre. InputError for a zero or
// non-finite column.
void setImageGeometry(codec::Image& im, const Mat4& pixelToFrame);

// A packed uint8 IMAGE of `dims` voxels (x fastest; dims.z = 1 for a 2D
// image) whose voxel (i, j, k) lies at pixelToFrame * (i, j, k, 1);
// `components` bytes a voxel (3: RGB).
std::string packCentredImage(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                             const Mat4& pixelToFrame, double timeS, int components = 1);
// The box of `size` voxels at `offset` of that uint8 volume (`voxels` the
// whole volume's) as an IMAGE sub-volume: size and matrix are the whole
// volume's, the data the box's, x fastest.
std::string packSubVolume(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                          const Mat4& pixelToFrame, const Index3& offset, const Index3& size, double timeS);
// A frame (uint8 or uint16, 16-bit pixels in the byte order asked for) as a
// packed 2D IMAGE at pixelToFrame, stamped `time`.
std::string packFrame(const std::string& device, const Frame& f, const Mat4& pixelToFrame, bool bigEndian,
                      WireTime time);

}  // namespace pp5::igtl::wire
