#pragma once
// What the OpenIGTLink server reads from its clients and answers them with,
// apart from any socket (so that a fuzz target drives it as the server does):
// the byte stream cut into whole, checked messages; PlusServer's commands
// (a STRING "CMD_<uid>" holding <Command Name="..." .../>) parsed and checked;
// and the server's own small messages packed (STATUS, CAPABILITY, the
// command's STRING "ACK_<uid>" reply, TRANSFORM).
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "core/transform.hpp"

namespace pp5::igtl {

// Device names are at most this long on the wire (longer ones are cut).
constexpr std::size_t kDeviceNameLength = 20;

// One whole message from a client.
struct Incoming {
  int version = 1;
  std::string type, device;
  std::string body;  // checked against the header's CRC
};

// Cuts a client's byte stream into messages. A stream that is not
// OpenIGTLink (a header version other than 1 to 3, a type or device name that
// is not printable ASCII), a body over `maxBody` bytes (however large the
// header claims, wrapping sizes included) or a body whose CRC differs from
// its header's is an InputError whose text says which, in one line: the
// server then logs it and drops the connection.
class MessageReader {
public:
  explicit MessageReader(std::size_t maxBody) : maxBody_(maxBody) {}
  // Appends `n` bytes and returns every message they complete.
  std::vector<Incoming> feed(const std::uint8_t* bytes, std::size_t n);

private:
  std::size_t maxBody_;
  std::vector<std::uint8_t> in_;
};

// A PlusServer command: the STRING device name's uid, the <Command> element's
// Name and its other attributes, in document order.
struct Command {
  std::string uid;
  std::string name;
  std::vector<std::pair<std::string, std::string>> attributes;
  // The attribute's value, or `otherwise` when it is absent.
  std::string attribute(const std::string& key, const std::string& otherwise = "") const;
  bool has(const std::string& key) const;
};

// Whether `m` is a command (a STRING whose device name starts with CMD_).
bool isCommand(const Incoming& m);
// The command it holds. InputError when the STRING body is malformed (length
// past its end, an encoding other than US-ASCII or UTF-8), the uid is empty or
// not printable, or the text is not one <Command Name="..."/> element.
Command parseCommand(const Incoming& m);

// Packed messages (header and body), version 1, CRC set.
std::string packStatus(int code, const std::string& device, const std::string& errorName, const std::string& text);
std::string packCapability(const std::string& device, const std::vector<std::string>& types);
// PlusServer's reply to CMD_<uid>: STRING ACK_<uid>, US-ASCII,
// <CommandReply Status="SUCCESS|FAIL" Message="..."/> (the message escaped).
std::string packCommandReply(const std::string& uid, bool ok, const std::string& message);
std::string packTransform(const std::string& device, const Mat4& m, double timeS);

}  // namespace pp5::igtl
