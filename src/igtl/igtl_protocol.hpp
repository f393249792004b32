#pragma once
// What the OpenIGTLink server reads from its clients and answers them with,
// apart from any socket (so that a fuzz target drives it as the server does):
// the byte stream cut into whole, checked messages; PlusServer's commands
// parsed and checked, in both forms PlusServer takes: a STRING "CMD_<uid>"
// holding <Command Name="..." .../> (answered by a STRING "ACK_<uid>"), and
// OpenIGTLink 3's COMMAND (answered by an RTS_COMMAND with the same id and
// the Status in its metadata); and the server's own small messages packed
// (STATUS, CAPABILITY, the replies, TRANSFORM), on igtl/igtl_codec.hpp.
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
  std::string body;  // checked against the header's CRC (for version 2, with its extended header and metadata)
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

// A PlusServer command: how it came (the STRING device name's uid, or the
// COMMAND's id and device name), the <Command> element's Name and its other
// attributes, in document order.
struct Command {
  bool v3 = false;         // an OpenIGTLink 3 COMMAND rather than a STRING
  std::string uid;         // STRING: CMD_<uid>; COMMAND: its id in decimal
  std::uint32_t id = 0;    // COMMAND's
  std::string device;      // COMMAND's device name (the reply's)
  std::string name;
  std::vector<std::pair<std::string, std::string>> attributes;
  // The attribute's value, or `otherwise` when it is absent.
  std::string attribute(const std::string& key, const std::string& otherwise = "") const;
  bool has(const std::string& key) const;
};

// Whether `m` is a command (a STRING whose device name starts with CMD_, or a COMMAND).
bool isCommand(const Incoming& m);
// What a reply to it needs (its form, uid or id, device), read without its
// text; InputError when even that cannot be read (its uid is empty, a
// COMMAND's content is short).
Command commandOf(const Incoming& m);
// The command it holds. InputError when the body is malformed (a length past
// its end, an encoding other than US-ASCII or UTF-8), the uid is empty, or
// the text is not one <Command Name="..."/> element (a COMMAND's name stands
// in for a missing Name).
Command parseCommand(const Incoming& m);

// Packed messages (header and body), version 1, CRC set.
std::string packStatus(int code, const std::string& device, const std::string& errorName, const std::string& text);
std::string packCapability(const std::string& device, const std::vector<std::string>& types);
// PlusServer's reply. To a STRING CMD_<uid>: STRING ACK_<uid>, US-ASCII,
// <CommandReply Status="SUCCESS|FAIL" Message="..."/> (the message escaped).
// To a COMMAND: RTS_COMMAND (header version 2) with its id, name and device,
// <Command><Result>true|false</Result><Message>...</Message></Command>, and
// the metadata Status (SUCCESS or FAIL) and Message (ErrorMessage too on FAIL).
std::string packCommandReply(const Command& c, bool ok, const std::string& message);
std::string packTransform(const std::string& device, const Mat4& m, double timeS);

}  // namespace pp5::igtl
