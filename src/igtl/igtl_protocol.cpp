#include "igtl/igtl_protocol.hpp"

#include <algorithm>
#include <sstream>

#include <fmt/format.h>
#include <pugixml.hpp>

#include "core/error.hpp"
#include "igtl/igtl_codec.hpp"
#include "igtl/igtl_wire.hpp"

namespace pp5::igtl {

namespace {

bool printable(const std::string& s) {
  return std::all_of(s.begin(), s.end(), [](char c) { return c >= 0x20 && c <= 0x7e; });
}

// US-ASCII on the wire, as PlusServer sends its replies.
std::string ascii(std::string s) {
  for (char& ch : s)
    if (static_cast<unsigned char>(ch) > 0x7e || (static_cast<unsigned char>(ch) < 0x20 && ch != '\n')) ch = '?';
  return s;
}

std::string xml(const pugi::xml_document& doc) {
  std::ostringstream text;
  doc.save(text, "", pugi::format_raw | pugi::format_no_declaration);
  return text.str();
}

codec::Body content(std::string c) {
  codec::Body b;
  b.content = std::move(c);
  return b;
}

}  // namespace

std::vector<Incoming> MessageReader::feed(const std::uint8_t* bytes, std::size_t n) {
  in_.insert(in_.end(), bytes, bytes + n);
  std::vector<Incoming> out;
  std::size_t at = 0;
  while (in_.size() - at >= codec::kHeaderBytes) {
    const codec::Header h = codec::readHeader(in_.data() + at);
    if (h.bodySize > maxBody_)
      throw InputError(fmt::format("{} message of {} bytes claimed, over the limit of {} bytes", h.type, h.bodySize,
                                   maxBody_));
    if (in_.size() - at < codec::kHeaderBytes + h.bodySize) break;
    const std::uint8_t* b = in_.data() + at + codec::kHeaderBytes;
    const std::uint64_t actual = codec::crc64(b, h.bodySize);
    if (h.crc != actual)
      throw InputError(fmt::format("the CRC of a {} message '{}' is {:016x} in its header but {:016x} in its body",
                                   h.type, h.device, h.crc, actual));
    Incoming m;
    m.version = h.version;
    m.type = h.type;
    m.device = h.device;
    m.body.assign(reinterpret_cast<const char*>(b), static_cast<std::size_t>(h.bodySize));
    at += codec::kHeaderBytes + static_cast<std::size_t>(h.bodySize);
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

bool isCommand(const Incoming& m) {
  return (m.type == "STRING" && m.device.rfind("CMD_", 0) == 0) || m.type == "COMMAND";
}

Command commandOf(const Incoming& m) {
  Command c;
  if (m.type == "COMMAND") {
    const codec::CommandContent cc = codec::readCommand(codec::readBody(m.version, m.body).content);
    c.v3 = true;
    c.id = cc.id;
    c.uid = std::to_string(cc.id);
    c.device = m.device;
    c.name = cc.name;
    return c;
  }
  c.uid = m.device.substr(4);
  if (c.uid.empty()) throw InputError("a command's device name is CMD_ with no uid after it");
  return c;
}

Command parseCommand(const Incoming& m) {
  Command c = commandOf(m);
  const codec::Body body = codec::readBody(m.version, m.body);
  int encoding = 3;
  std::string text;
  if (c.v3) {
    const codec::CommandContent cc = codec::readCommand(body.content);
    encoding = cc.encoding;
    text = cc.text;
  } else {
    const codec::Text t = codec::readString(body.content);
    encoding = t.encoding;
    text = t.text;
  }
  if (encoding != 3 && encoding != 106)
    throw InputError(fmt::format("command {}: text encoding {} (only US-ASCII, 3, and UTF-8, 106, are read)", c.uid,
                                 encoding));
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
  return codec::pack(1, "STATUS", device, {}, content(codec::statusContent(code, 0, errorName.substr(0, 19), text)));
}

std::string packCapability(const std::string& device, const std::vector<std::string>& types) {
  return codec::pack(1, "CAPABILITY", device, {}, content(codec::capabilityContent(types)));
}

std::string packCommandReply(const Command& c, bool ok, const std::string& message) {
  const std::string said = ascii(message);
  pugi::xml_document doc;
  if (!c.v3) {
    pugi::xml_node n = doc.append_child("CommandReply");
    n.append_attribute("Status") = ok ? "SUCCESS" : "FAIL";
    n.append_attribute("Message") = said.c_str();
    return codec::pack(1, "STRING", ("ACK_" + c.uid).substr(0, kDeviceNameLength), {},
                       content(codec::stringContent(3, xml(doc))));
  }
  pugi::xml_node n = doc.append_child("Command");
  n.append_child("Result").text() = ok ? "true" : "false";
  n.append_child("Message").text() = said.c_str();
  codec::Body b;
  b.content = codec::commandContent({c.id, c.name, 3, xml(doc)});
  b.messageId = c.id;
  b.metadata = {{"Status", ok ? "SUCCESS" : "FAIL"}, {"Message", said}};
  if (!ok) b.metadata.emplace_back("ErrorMessage", said);
  return codec::pack(2, "RTS_COMMAND", c.device, {}, b);
}

std::string packTransform(const std::string& device, const Mat4& m, double timeS) {
  return wire::packTransform(device.substr(0, kDeviceNameLength), m, timeS);
}

}  // namespace pp5::igtl
