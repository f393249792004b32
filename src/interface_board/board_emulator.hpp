#pragma once
// The board emulator: makes an interface board appear to libusb through
// umockdev, so that the real driver runs unmodified against it.
//
// umockdev's testbed gives the board a sysfs entry (descriptors, bus and
// device numbers) and a /dev/bus/usb node whose ioctls (the usbdevfs calls
// libusb makes: SUBMITURB, REAPURBNDELAY, DISCARDURB, CLAIMINTERFACE, ...)
// arrive here. A program that loads libumockdev-preload.so with this
// process's UMOCKDEV_DIR sees the board; the emulator starts such a program
// as its child (see emulator_main.cpp).
//
// Frames stream at a set rate from the moment the host sends Start, encoded
// in the wire format of wire.hpp, with faults injected on request.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "interface_board/wire.hpp"
#include "core/enum_names.hpp"

namespace pp5::board {

enum class FaultKind {
  BadCrc,   // one payload byte flipped after the CRCs are computed
  Drop,     // one 512-byte packet of the frame never arrives
  Short,    // the frame ends after half its payload; the next frame follows at once
  Stall,    // the bulk endpoint halts before the frame; the host must clear it
  Unplug,   // the board disappears before the frame (and comes back if reconnectAfterS > 0)
};
FaultKind faultKindFromName(const std::string& name);  // bad_crc | drop | short | stall | unplug
const char* faultKindName(FaultKind k);

struct Fault {
  FaultKind kind;
  std::uint32_t frame = 0;      // applied to this frame index (0-based)
  double reconnectAfterS = 0.0; // Unplug only: 0 = gone for good
};
// "KIND@FRAME" or "unplug@FRAME:SECONDS"; InputError on anything else.
Fault parseFault(const std::string& spec);

struct EmulatorOptions {
  std::uint16_t vendorId = 0, productId = 0;  // 0 = the defaults of usb_protocol.hpp
  double fps = 30.0;                          // 0 = as fast as the host reads
  std::vector<Fault> faults;
  // Frames carry the time the board sends them (its clock, microseconds since
  // it started), as a real board stamps capture time; true keeps the source's.
  bool keepTimestamps = false;
};

struct EmulatorStats {
  std::uint64_t framesSent = 0, bytesSent = 0, urbsCompleted = 0;
  std::uint64_t faultsInjected = 0, unplugs = 0, reconnects = 0, stallsCleared = 0;
};

class BoardEmulator {
public:
  // The frames the board will stream, in order (sequence numbers are set
  // here). Creates the umockdev testbed (this sets UMOCKDEV_DIR in this
  // process's environment, which children inherit) and plugs the board in.
  BoardEmulator(std::vector<WireFrame> frames, EmulatorOptions options);
  ~BoardEmulator();
  BoardEmulator(const BoardEmulator&) = delete;
  BoardEmulator& operator=(const BoardEmulator&) = delete;

  // Runs `argv` with the umockdev preload library and waits for it, serving
  // the board meanwhile. Returns the child's exit status (128 + signal when
  // it was killed).
  int runChild(const std::vector<std::string>& argv);

  EmulatorStats stats() const;
  struct Impl;

private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace pp5::board

namespace pp5 {

template <>
struct EnumNames<board::FaultKind> {
  static constexpr std::string_view key = "--fault";
  static constexpr std::array<std::pair<board::FaultKind, std::string_view>, 5> names{{
      {board::FaultKind::BadCrc, "bad_crc"},
      {board::FaultKind::Drop, "drop"},
      {board::FaultKind::Short, "short"},
      {board::FaultKind::Stall, "stall"},
      {board::FaultKind::Unplug, "unplug"}}};
};

}  // namespace pp5
