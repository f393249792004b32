#pragma once
// The OpenIGTLink wire format, as the client, the server and
// pp5echo-igtl-server read and write it: the 58-byte header with its CRC-64,
// the version 2 body (extended header, content, metadata) that OpenIGTLink 3
// peers send, and the contents pp5echo uses: IMAGE, TRANSFORM, STATUS,
// STRING, CAPABILITY, COMMAND and RTS_COMMAND. All numbers are big-endian on
// the wire. The project's own (docs/dependencies.md says why): Debian 12's
// libopenigtlink is 1.11, which speaks neither the version 2 body nor
// COMMAND; the tests use that library as the independent peer.
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace pp5::igtl::codec {

constexpr std::size_t kHeaderBytes = 58;
constexpr std::size_t kNameBytes = 20;       // a device name's field
constexpr std::size_t kTypeBytes = 12;       // a type's field
constexpr std::size_t kImageHeaderBytes = 72;
constexpr std::size_t kTransformBytes = 48;
constexpr std::size_t kCommandHeaderBytes = 138;  // id, name[128], encoding, length

// STATUS codes (OpenIGTLink's).
enum StatusCode : int {
  kStatusOk = 1,
  kStatusUnknownError = 2,
  kStatusNotFound = 4,
  kStatusChecksumError = 9,
  kStatusUnknownInstruction = 12,
};
// IMAGE scalar types and byte orders.
constexpr int kUint8 = 3, kUint16 = 5;
constexpr int kBigEndian = 1, kLittleEndian = 2;

// OpenIGTLink's CRC-64 (ECMA-182, most significant bit first, no reflection).
std::uint64_t crc64(const std::uint8_t* data, std::size_t n, std::uint64_t crc = 0);

// The header's timestamp: whole seconds and a 32-bit binary fraction. Encoding
// rounds to the nearest 2^-32 s; negative or too-large times are an InputError.
struct WireTime {
  std::uint32_t sec = 0;
  std::uint32_t frac = 0;
};
WireTime encodeTime(double seconds);
double decodeTime(WireTime t);

struct Header {
  int version = 1;
  std::string type, device;
  WireTime time;
  std::uint64_t bodySize = 0;
  std::uint64_t crc = 0;
};
// The header at p (kHeaderBytes). InputError when it is not OpenIGTLink: a
// version other than 1 to 3, a type or device name that is not printable ASCII.
Header readHeader(const std::uint8_t* p);

// A message's body apart from its framing: for header version 2 and 3, the
// extended header's message id and the metadata (key, value) that follow the
// content; for version 1 the content is the body.
struct Body {
  std::string content;
  std::uint32_t messageId = 0;
  std::vector<std::pair<std::string, std::string>> metadata;
  std::string meta(const std::string& key) const;  // "" when absent
};
// InputError when a version 2 body's sizes do not add up.
Body readBody(int version, const std::string& body);

// A whole message: header (CRC set) and body. Version 1 sends `b.content`
// alone; version 2 the extended header, the content and the metadata.
std::string pack(int version, const std::string& type, const std::string& device, WireTime time, const Body& b);

// IMAGE: its header fields and where its voxels lie in the content.
struct Image {
  int components = 1;
  int scalarType = kUint8;
  int endian = kLittleEndian;
  int coordinate = 1;            // 1 RAS, 2 LPS
  int size[3] = {1, 1, 1};
  // The voxel axes times the spacing (i, j, k), then the centre of the
  // voxels: OpenIGTLink's (t, s, n, p).
  float matrix[12] = {1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0};
  int subOffset[3] = {0, 0, 0};
  int subSize[3] = {1, 1, 1};
  std::size_t dataOffset = kImageHeaderBytes;  // in the content
  std::size_t voxelBytes() const;              // of the sub-volume, as the header says
};
// InputError for a content shorter than its header, or than the voxels it declares.
Image readImage(const std::string& content);
// The content: header then `n` bytes of voxels.
std::string imageContent(const Image& im, const std::uint8_t* voxels, std::size_t n);

// TRANSFORM: the upper 3x4 of a 4x4 matrix, column by column (float32).
// m is row-major, m[row * 4 + col].
void readTransform(const std::string& content, double m[16]);
std::string transformContent(const double m[16]);

std::string statusContent(int code, std::int64_t subCode, const std::string& errorName, const std::string& text);
struct Status {
  int code = 0;
  std::int64_t subCode = 0;
  std::string errorName, text;
};
Status readStatus(const std::string& content);

// STRING: a MIB encoding (3 US-ASCII, 106 UTF-8) and the text.
std::string stringContent(int encoding, const std::string& text);
struct Text {
  int encoding = 3;
  std::string text;
};
Text readString(const std::string& content);

std::string capabilityContent(const std::vector<std::string>& types);
std::vector<std::string> readCapability(const std::string& content);

// COMMAND and RTS_COMMAND (OpenIGTLink 3): an id, a name, an encoding and the text.
struct CommandContent {
  std::uint32_t id = 0;
  std::string name;
  int encoding = 3;
  std::string text;
};
std::string commandContent(const CommandContent& c);
CommandContent readCommand(const std::string& content);

}  // namespace pp5::igtl::codec
