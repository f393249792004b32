#pragma once
// The interface board as a USB device: identity, endpoint and vendor
// requests. Shared by the libusb driver and the umockdev emulator; the wire
// format of the frames on the bulk endpoint is in wire.hpp. docs/protocol.md
// describes both.
#include <cstdint>

namespace pp5::board {

// pid.codes' test VID/PID: a vendor-class device with one interface.
constexpr std::uint16_t kDefaultVendorId = 0x1209;
constexpr std::uint16_t kDefaultProductId = 0x0001;
constexpr int kInterface = 0;
constexpr std::uint8_t kBulkInEndpoint = 0x81;
constexpr int kBulkMaxPacket = 512;  // high-speed bulk

// Vendor control requests (bmRequestType 0x40 host-to-device, or 0xC0 for
// GetStatus), recipient device, wIndex 0.
enum class Request : std::uint8_t {
  Start = 0x01,         // begin streaming frames on the bulk endpoint
  Stop = 0x02,          // stop after the current frame
  SetFrameRate = 0x03,  // wValue = frames per second x 100 (0 = as fast as possible)
  SetWindow = 0x04,     // data: x, y, width, height (u16 LE each); 0 width = full frame
  GetStatus = 0x05,     // data in: BoardStatus (kStatusBytes)
  Reset = 0x06,         // drop any partial frame and restart the sequence numbers at 0
};

// GetStatus reply, little-endian u32 fields in this order.
struct BoardStatus {
  std::uint32_t streaming = 0;      // 1 while started
  std::uint32_t framesSent = 0;     // since power-on
  std::uint32_t framesDropped = 0;  // frames the board could not send in time
  std::uint32_t frameRateX100 = 0;
  std::uint32_t windowX = 0, windowY = 0, windowW = 0, windowH = 0;
};
constexpr int kStatusBytes = 32;

}  // namespace pp5::board
