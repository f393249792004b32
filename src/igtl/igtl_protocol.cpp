#include "igtl/igtl_protocol.hpp"

#include <algorithm>
#include <sstream>

#include <fmt/format.h>
#include <igtlCapabilityMessage.h>
#include <igtlStatusMessage.h>
#include <igtlStringMessage.h>
#include <igtlTransformMessage.h>
#include <igtl_header.h>
#include <igtl_util.h>
#include <pugixml.hpp>

#include "core/error.hpp"
#include "igtl/igtl_wire.hpp"

namespace pp5::igtl {

namespace {

std::uint64_t bigEndian64(const std::uint8_t* p) {
  std::uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v = (v << 8) | p[i];
  return v;
}

// A NUL-padded name field; InputError when it holds anything but printable
// ASCII before its padding (a stream that is not OpenIGTLink).
std::string nameField(const std::uint8_t* p, std::size_t n, const char* what) {
  std::size_t len = 0;
  while (len < n && p[len] != 0) ++len;
  for (std::size_t i = 0; i < len; ++i)
    if (p[i] < 0x20 || p[i] > 0x7e)
      throw InputError(fmt::format("not OpenIGTLink: the header's {} holds byte 0x{:02x}", what, p[i]));
  return {reinterpret_cast<const char*>(p), len};
}

std::string packed(::igtl::MessageBase& m) {
  m.Pack();
  return {static_cast<const char*>(m.GetPackPointer()), static_cast<std::size_t>(m.GetPackSize())};
}

bool printable(const std::string& s) {
  return std::all_of(s.begin(), s.end(), [](char c) { return c >= 0x20 && c <= 0x7e; });
}

}  // namespace

std::vector<Incoming> MessageReader::feed(const std::uint8_t* bytes, std::size_t n) {
  in_.insert(in_.end(), bytes, bytes + n);
  std::vector<Incoming> out;
  std::size_t at = 0;
  while (in_.size() - at >= IGTL_HEADER_SIZE) {
    const std::uint8_t* h = in_.data() + at;
    const int version = (h[0] << 8) | h[1];
    if (version < 1 || version > 3) throw InputError(fmt::format("not OpenIGTLink: header version {}", version));
    Incoming m;
    m.version = version;
    m.type = nameField(h + 2, 12, "type");
    m.device = nameField(h + 14, 20, "device name");
    if (m.type.empty()) throw InputError("not OpenIGTLink: the header's type is empty");
    const std::uint64_t body = bigEndian64(h + 42);
    if (body > maxBody_)
      throw InputError(fmt::format("{} message of {} bytes claimed, over the limit of {} bytes", m.type, body,
                                   maxBody_));
    if (in_.size() - at < IGTL_HEADER_SIZE + body) break;
    const std::uint64_t crc = bigEndian64(h + 50);
    auto* b = const_cast<unsigned char*>(h + IGTL_HEADER_SIZE);
    const std::uint64_t actual = crc64(b, body, 0);
    if (crc != actual)
      throw InputError(fmt::format("the CRC of a {} message '{}' is {:016x} in its header but {:016x} in its body",
                                   m.type, m.device, crc, actual));
    m.body.assign(reinterpret_cast<const char*>(b), static_cast<std::size_t>(body));
    at += IGTL_HEADER_SIZE + static_cast<std::size_t>(body);
    out.push_back(std::move(m));
  }
  in_.erase(in_.begin(), in_.begin() + static_cast<std::ptrdiff_t>(at));
  return out;
}

std::string Command::attribute(const std::string& key, const std::string& otherwise) const {
  for (const auto& [k, v] : attributes)
    if (k == key) return v;
  return otherwise;
}

bool Command::has(const std::string& key) const {
  return std::any_of(attributes.begin(), attributes.end(), [&](const auto& a) { return a.first == key; });
}

bool isCommand(const Incoming& m) { return m.type == "STRING" && m.device.rfind("CMD_", 0) == 0; }

Command parseCommand(const Incoming& m) {
  Command c;
  c.uid = m.device.substr(4);
  if (c.uid.empty()) throw InputError("a command's device name is CMD_ with no uid after it");
  // STRING: encoding (MIBenum) and length, both 16-bit big-endian, then the text.
  if (m.body.size() < 4) throw InputError(fmt::format("command {}: a STRING body of {} bytes", c.uid, m.body.size()));
  const auto* b = reinterpret_cast<const std::uint8_t*>(m.body.data());
  const int encoding = (b[0] << 8) | b[1];
  const std::size_t length = static_cast<std::size_t>((b[2] << 8) | b[3]);
  if (encoding != 3 && encoding != 106)
    throw InputError(fmt::format("command {}: text encoding {} (only US-ASCII, 3, and UTF-8, 106, are read)", c.uid,
                                 encoding));
  if (length > m.body.size() - 4)
    throw InputError(fmt::format("command {}: a text of {} bytes claimed in a body of {}", c.uid, length,
                                 m.body.size()));
  const std::string text = m.body.substr(4, length);
  pugi::xml_document doc;
  const pugi::xml_parse_result r = doc.load_buffer(text.data(), text.size(), pugi::parse_default, pugi::encoding_utf8);
  if (!r) throw InputError(fmt::format("command {}: not XML ({} at byte {})", c.uid, r.description(), r.offset));
  const pugi::xml_node root = doc.document_element();
  if (std::string(root.name()) != "Command" || root.next_sibling())
    throw InputError(fmt::format("command {}: the text is not one <Command> element", c.uid));
  for (const pugi::xml_attribute a : root.attributes()) {
    const std::string key = a.name();
    if (key == "Name") c.name = a.value();
    else c.attributes.emplace_back(key, a.value());
  }
  if (c.name.empty()) throw InputError(fmt::format("command {}: <Command> has no Name", c.uid));
  if (!printable(c.name)) throw InputError(fmt::format("command {}: its Name is not printable ASCII", c.uid));
  return c;
}

std::string packStatus(int code, const std::string& device, const std::string& errorName, const std::string& text) {
  auto s = ::igtl::StatusMessage::New();
  s->SetDeviceName(device.substr(0, wire::kMaxDeviceName).c_str());
  s->SetCode(code);
  s->SetSubCode(0);
  s->SetErrorName(errorName.substr(0, 19).c_str());  // a 20-byte field
  s->SetStatusString(text.c_str());
  return packed(*s);
}

std::string packCapability(const std::string& device, const std::vector<std::string>& types) {
  auto cap = ::igtl::CapabilityMessage::New();
  cap->SetDeviceName(device.substr(0, wire::kMaxDeviceName).c_str());
  cap->SetTypes(types);
  return packed(*cap);
}

std::string packCommandReply(const std::string& uid, bool ok, const std::string& message) {
  pugi::xml_document doc;
  pugi::xml_node n = doc.append_child("CommandReply");
  n.append_attribute("Status") = ok ? "SUCCESS" : "FAIL";
  std::string ascii = message;  // US-ASCII on the wire, as PlusServer sends it
  for (char& ch : ascii)
    if (static_cast<unsigned char>(ch) > 0x7e || (static_cast<unsigned char>(ch) < 0x20 && ch != '\n')) ch = '?';
  n.append_attribute("Message") = ascii.c_str();
  std::ostringstream text;
  doc.save(text, "", pugi::format_raw | pugi::format_no_declaration);
  auto s = ::igtl::StringMessage::New();
  s->SetDeviceName(("ACK_" + uid).substr(0, wire::kMaxDeviceName).c_str());
  s->SetEncoding(3);
  s->SetString(text.str().c_str());
  return packed(*s);
}

std::string packTransform(const std::string& device, const Mat4& m, double timeS) {
  auto t = ::igtl::TransformMessage::New();
  t->SetDeviceName(device.substr(0, wire::kMaxDeviceName).c_str());
  ::igtl::Matrix4x4 f;
  wire::toIgtl(m, f);
  t->SetMatrix(f);
  const wire::WireTime w = wire::encodeTime(std::max(0.0, timeS));
  t->SetTimeStamp(w.sec, w.frac);
  return packed(*t);
}

}  // namespace pp5::igtl
