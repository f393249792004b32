#include "igtl/igtl_codec.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::igtl::codec {

namespace {

constexpr double kFracScale = 4294967296.0;  // 2^32
constexpr std::size_t kExtendedHeaderBytes = 12;

// The CRC's tables, eight bytes at a time ("slicing by 8"): t[0][b] is the
// CRC register after byte b went in at the top, t[k][b] after k more zero
// bytes, so that a 64-bit word XORed into the register takes one look-up
// per byte, all independent.
using CrcTables = std::array<std::array<std::uint64_t, 256>, 8>;
CrcTables crcTables() {
  constexpr std::uint64_t poly = 0x42F0E1EBA9EA3693ull;  // ECMA-182
  CrcTables t{};
  for (std::uint64_t i = 0; i < 256; ++i) {
    std::uint64_t c = i << 56;
    for (int b = 0; b < 8; ++b) c = (c & (1ull << 63)) ? (c << 1) ^ poly : c << 1;
    t[0][i] = c;
  }
  for (std::size_t k = 1; k < 8; ++k)
    for (std::size_t i = 0; i < 256; ++i) t[k][i] = (t[k - 1][i] << 8) ^ t[0][t[k - 1][i] >> 56];
  return t;
}

// Big-endian writing and reading.
class Out {
public:
  explicit Out(std::string& s) : s_(s) {}
  template <class T>
  void put(T v) {
    const auto u = static_cast<std::make_unsigned_t<T>>(v);
    for (int i = static_cast<int>(sizeof(T)) - 1; i >= 0; --i) s_.push_back(static_cast<char>((u >> (8 * i)) & 0xff));
  }
  void f32(float v) { put(std::bit_cast<std::uint32_t>(v)); }
  void name(const std::string& v, std::size_t n) {
    std::string f = v.substr(0, n);
    f.resize(n, '\0');
    s_ += f;
  }
  void bytes(const void* p, std::size_t n) { s_.append(static_cast<const char*>(p), n); }

private:
  std::string& s_;
};

class In {
public:
  In(const std::string& s, const char* what) : p_(reinterpret_cast<const std::uint8_t*>(s.data())), n_(s.size()), what_(what) {}
  template <class T>
  T get() {
    need(sizeof(T));
    std::make_unsigned_t<T> u = 0;
    for (std::size_t i = 0; i < sizeof(T); ++i) u = static_cast<std::make_unsigned_t<T>>((u << 8) | p_[at_ + i]);
    at_ += sizeof(T);
    return static_cast<T>(u);
  }
  float f32() { return std::bit_cast<float>(get<std::uint32_t>()); }
  std::string name(std::size_t n) {
    need(n);
    std::size_t len = 0;
    while (len < n && p_[at_ + len] != 0) ++len;
    std::string s(reinterpret_cast<const char*>(p_ + at_), len);
    at_ += n;
    return s;
  }
  std::string rest(std::size_t n) {
    need(n);
    std::string s(reinterpret_cast<const char*>(p_ + at_), n);
    at_ += n;
    return s;
  }
  std::size_t at() const { return at_; }
  std::size_t left() const { return n_ - at_; }

private:
  void need(std::size_t k) const {
    if (k > n_ - at_) throw InputError(fmt::format("a {} body of {} bytes is too short", what_, n_));
  }
  const std::uint8_t* p_;
  std::size_t n_, at_ = 0;
  const char* what_;
};

std::string nameField(const std::uint8_t* p, std::size_t n, const char* what) {
  std::size_t len = 0;
  while (len < n && p[len] != 0) ++len;
  for (std::size_t i = 0; i < len; ++i)
    if (p[i] < 0x20 || p[i] > 0x7e)
      throw InputError(fmt::format("not OpenIGTLink: the header's {} holds byte 0x{:02x}", what, p[i]));
  return {reinterpret_cast<const char*>(p), len};
}

std::uint64_t be64(const std::uint8_t* p) {
  std::uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v = (v << 8) | p[i];
  return v;
}

}  // namespace

std::uint64_t crc64(const std::uint8_t* data, std::size_t n, std::uint64_t crc) {
  static const CrcTables t = crcTables();
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const std::uint64_t w = crc ^ be64(data + i);
    crc = t[7][w >> 56] ^ t[6][(w >> 48) & 0xff] ^ t[5][(w >> 40) & 0xff] ^ t[4][(w >> 32) & 0xff] ^
          t[3][(w >> 24) & 0xff] ^ t[2][(w >> 16) & 0xff] ^ t[1][(w >> 8) & 0xff] ^ t[0][w & 0xff];
  }
  for (; i < n; ++i) crc = t[0][((crc >> 56) ^ data[i]) & 0xff] ^ (crc << 8);
  return crc;
}

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

Header readHeader(const std::uint8_t* p) {
  Header h;
  h.version = (p[0] << 8) | p[1];
  if (h.version < 1 || h.version > 3) throw InputError(fmt::format("not OpenIGTLink: header version {}", h.version));
  h.type = nameField(p + 2, kTypeBytes, "type");
  if (h.type.empty()) throw InputError("not OpenIGTLink: the header's type is empty");
  h.device = nameField(p + 14, kNameBytes, "device name");
  const std::uint64_t t = be64(p + 34);
  h.time = {static_cast<std::uint32_t>(t >> 32), static_cast<std::uint32_t>(t & 0xffffffffu)};
  h.bodySize = be64(p + 42);
  h.crc = be64(p + 50);
  return h;
}

std::string Body::meta(const std::string& key) const {
  for (const auto& [k, v] : metadata)
    if (k == key) return v;
  return {};
}

Body readBody(int version, const std::string& body) {
  Body b;
  if (version < 2) {
    b.content = body;
    return b;
  }
  In in(body, "version 2 message");
  const auto ext = in.get<std::uint16_t>();
  const auto metaHeader = in.get<std::uint16_t>();
  const auto metaSize = in.get<std::uint32_t>();
  b.messageId = in.get<std::uint32_t>();
  if (ext < kExtendedHeaderBytes || ext > body.size() ||
      static_cast<std::uint64_t>(ext) + metaHeader + metaSize > body.size())
    throw InputError(fmt::format("a version 2 body of {} bytes with an extended header of {}, metadata of {} + {}",
                                 body.size(), ext, metaHeader, metaSize));
  const std::size_t contentBytes = body.size() - ext - metaHeader - metaSize;
  b.content = body.substr(ext, contentBytes);
  if (metaHeader == 0) return b;
  In meta(body.substr(ext + contentBytes), "metadata");
  const auto count = meta.get<std::uint16_t>();
  if (metaHeader != 2 + 8u * count) throw InputError(fmt::format("metadata of {} entries in a header of {} bytes", count, metaHeader));
  std::vector<std::pair<std::uint16_t, std::uint32_t>> sizes;
  for (int i = 0; i < count; ++i) {
    const auto key = meta.get<std::uint16_t>();
    (void)meta.get<std::uint16_t>();  // the value's encoding
    sizes.emplace_back(key, meta.get<std::uint32_t>());
  }
  for (const auto& [k, v] : sizes) {
    std::string key = meta.rest(k);
    b.metadata.emplace_back(std::move(key), meta.rest(v));
  }
  return b;
}

std::string pack(int version, const std::string& type, const std::string& device, WireTime time, const Body& b) {
  std::string body;
  if (version >= 2) {
    std::string metaHead, metaData;
    Out mh(metaHead), md(metaData);
    mh.put(static_cast<std::uint16_t>(b.metadata.size()));
    for (const auto& [k, v] : b.metadata) {
      mh.put(static_cast<std::uint16_t>(k.size()));
      mh.put(static_cast<std::uint16_t>(3));  // US-ASCII
      mh.put(static_cast<std::uint32_t>(v.size()));
      md.bytes(k.data(), k.size());
      md.bytes(v.data(), v.size());
    }
    if (b.metadata.empty()) metaHead.clear();
    Out o(body);
    o.put(static_cast<std::uint16_t>(kExtendedHeaderBytes));
    o.put(static_cast<std::uint16_t>(metaHead.size()));
    o.put(static_cast<std::uint32_t>(metaData.size()));
    o.put(b.messageId);
    body += b.content;
    body += metaHead;
    body += metaData;
  } else {
    body = b.content;
  }
  std::string m;
  m.reserve(kHeaderBytes + body.size());
  Out o(m);
  o.put(static_cast<std::uint16_t>(version));
  o.name(type, kTypeBytes);
  o.name(device, kNameBytes);
  o.put((static_cast<std::uint64_t>(time.sec) << 32) | time.frac);
  o.put(static_cast<std::uint64_t>(body.size()));
  o.put(crc64(reinterpret_cast<const std::uint8_t*>(body.data()), body.size()));
  m += body;
  return m;
}

std::size_t Image::voxelBytes() const {
  const std::size_t scalar = scalarType == kUint16 ? 2 : scalarType == kUint8 ? 1 : 0;
  return static_cast<std::size_t>(subSize[0]) * static_cast<std::size_t>(subSize[1]) *
         static_cast<std::size_t>(subSize[2]) * static_cast<std::size_t>(components) * scalar;
}

Image readImage(const std::string& content) {
  In in(content, "IMAGE");
  Image im;
  (void)in.get<std::uint16_t>();  // the image header's version
  im.components = in.get<std::uint8_t>();
  im.scalarType = in.get<std::uint8_t>();
  im.endian = in.get<std::uint8_t>();
  im.coordinate = in.get<std::uint8_t>();
  for (int& s : im.size) s = in.get<std::uint16_t>();
  for (float& m : im.matrix) m = in.f32();
  for (int& o : im.subOffset) o = in.get<std::uint16_t>();
  for (int& s : im.subSize) s = in.get<std::uint16_t>();
  im.dataOffset = in.at();
  return im;
}

std::string imageContent(const Image& im, const std::uint8_t* voxels, std::size_t n) {
  std::string s;
  s.reserve(kImageHeaderBytes + n);
  Out o(s);
  o.put(static_cast<std::uint16_t>(1));
  o.put(static_cast<std::uint8_t>(im.components));
  o.put(static_cast<std::uint8_t>(im.scalarType));
  o.put(static_cast<std::uint8_t>(im.endian));
  o.put(static_cast<std::uint8_t>(im.coordinate));
  for (const int v : im.size) o.put(static_cast<std::uint16_t>(v));
  for (const float m : im.matrix) o.f32(m);
  for (const int v : im.subOffset) o.put(static_cast<std::uint16_t>(v));
  for (const int v : im.subSize) o.put(static_cast<std::uint16_t>(v));
  o.bytes(voxels, n);
  return s;
}

void readTransform(const std::string& content, double m[16]) {
  In in(content, "TRANSFORM");
  float f[12];
  for (float& v : f) v = in.f32();
  for (int col = 0; col < 4; ++col)
    for (int row = 0; row < 3; ++row) m[row * 4 + col] = static_cast<double>(f[col * 3 + row]);
  m[12] = m[13] = m[14] = 0.0;
  m[15] = 1.0;
}

std::string transformContent(const double m[16]) {
  std::string s;
  Out o(s);
  for (int col = 0; col < 4; ++col)
    for (int row = 0; row < 3; ++row) o.f32(static_cast<float>(m[row * 4 + col]));
  return s;
}

std::string statusContent(int code, std::int64_t subCode, const std::string& errorName, const std::string& text) {
  std::string s;
  Out o(s);
  o.put(static_cast<std::uint16_t>(code));
  o.put(subCode);
  o.name(errorName, 20);
  o.bytes(text.data(), text.size());
  s.push_back('\0');
  return s;
}

Status readStatus(const std::string& content) {
  In in(content, "STATUS");
  Status st;
  st.code = in.get<std::uint16_t>();
  st.subCode = in.get<std::int64_t>();
  st.errorName = in.name(20);
  std::string text = in.rest(in.left());
  st.text = text.substr(0, text.find('\0'));
  return st;
}

std::string stringContent(int encoding, const std::string& text) {
  if (text.size() > 0xffff) throw InputError(fmt::format("a STRING of {} bytes (at most 65535)", text.size()));
  std::string s;
  Out o(s);
  o.put(static_cast<std::uint16_t>(encoding));
  o.put(static_cast<std::uint16_t>(text.size()));
  o.bytes(text.data(), text.size());
  return s;
}

Text readString(const std::string& content) {
  In in(content, "STRING");
  Text t;
  t.encoding = in.get<std::uint16_t>();
  const auto n = in.get<std::uint16_t>();
  if (n > in.left()) throw InputError(fmt::format("a STRING of {} bytes claimed in a body of {}", n, content.size()));
  t.text = in.rest(n);
  return t;
}

std::string capabilityContent(const std::vector<std::string>& types) {
  std::string s;
  Out o(s);
  for (const auto& t : types) o.name(t, kTypeBytes);
  return s;
}

std::vector<std::string> readCapability(const std::string& content) {
  In in(content, "CAPABILITY");
  std::vector<std::string> out;
  while (in.left() >= kTypeBytes) out.push_back(in.name(kTypeBytes));
  return out;
}

std::string commandContent(const CommandContent& c) {
  std::string s;
  Out o(s);
  o.put(c.id);
  o.name(c.name, 128);
  o.put(static_cast<std::uint16_t>(c.encoding));
  o.put(static_cast<std::uint32_t>(c.text.size()));
  o.bytes(c.text.data(), c.text.size());
  return s;
}

CommandContent readCommand(const std::string& content) {
  In in(content, "COMMAND");
  CommandContent c;
  c.id = in.get<std::uint32_t>();
  c.name = in.name(128);
  c.encoding = in.get<std::uint16_t>();
  const auto n = in.get<std::uint32_t>();
  if (n > in.left()) throw InputError(fmt::format("a COMMAND text of {} bytes claimed in a body of {}", n, content.size()));
  c.text = in.rest(n);
  return c;
}

}  // namespace pp5::igtl::codec
