#pragma once
// The interface board's wire format: one frame is a fixed 160-byte header
// followed by the pixel rows, all little-endian. The full layout, byte by
// byte, is in docs/protocol.md ("Interface board").
//
// Bulk transfers cut the byte stream anywhere: a frame may span many
// transfers and a transfer may end in the middle of a header. FrameDecoder is
// an incremental parser that takes the bytes as they come; after a bad CRC, a
// lost packet or a frame cut short it looks for the next frame's magic and
// carries on, counting every error. Its memory is bounded by one header plus
// Limits::maxPayloadBytes, whatever the input.
#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

namespace pp5::board {

constexpr std::uint32_t kMagic = 0x46354850u;  // bytes "PH5F" on the wire
constexpr std::uint16_t kVersion = 1;
constexpr std::size_t kHeaderBytes = 160;

// What the header's pose field holds.
enum class PoseKind : std::uint8_t {
  None = 0,       // no tracking for this frame
  ArmCounts = 1,  // the 3-DOF arm's raw 12-bit A/D counts: x, y, theta
  Matrix = 2,     // a 6-DOF tracker's ProbeToTracker, row-major 3x4, mm
};

// Header flag bits.
enum : std::uint32_t {
  kFlagImageInvalid = 1u << 0,  // the scanner marked the image invalid
  kFlagPoseInvalid = 1u << 1,   // the tracker reported no valid pose
  kFlagEndOfStream = 1u << 2,   // the last frame: the scanner was frozen (the host ends the stream)
};

// One decoded frame (or one frame to encode).
struct WireFrame {
  std::uint32_t sequence = 0;     // increments by one per frame sent
  std::uint64_t timestampUs = 0;  // the board's clock when the frame was captured
  std::uint16_t width = 0, height = 0;
  std::uint8_t bytesPerPixel = 1;  // 1 or 2 (16-bit little-endian)
  PoseKind poseKind = PoseKind::None;
  std::uint32_t flags = 0;
  std::array<std::uint16_t, 3> armCounts{};  // valid when poseKind == ArmCounts (0..4095)
  std::array<double, 12> matrix{};           // valid when poseKind == Matrix: rows 0..2 of a 4x4
  std::vector<std::uint8_t> pixels;          // width * height * bytesPerPixel, row-major
};

// CRC-32 (IEEE 802.3, as zlib computes it).
std::uint32_t crc32(std::span<const std::uint8_t> bytes, std::uint32_t crc = 0);

// Appends the frame's header and payload to `out`. Throws InputError when the
// frame is inconsistent (pixel count, bytes per pixel, counts over 4095).
void encodeFrame(const WireFrame& f, std::vector<std::uint8_t>& out);

// Bounds that a header must respect to be believed. A header that breaks one
// is treated as garbage (counted in badHeaders) and the decoder resyncs; a
// header claiming a 4 GB frame never causes a 4 GB allocation.
struct DecoderLimits {
  std::uint32_t maxPayloadBytes = 16u << 20;
  std::uint16_t maxWidth = 4096, maxHeight = 4096;
};

struct DecoderCounters {
  std::uint64_t bytesIn = 0;          // everything fed
  std::uint64_t frames = 0;           // complete frames handed out
  std::uint64_t headerCrcErrors = 0;  // a magic whose header CRC did not match
  std::uint64_t payloadCrcErrors = 0; // a good header whose payload CRC did not match
  std::uint64_t badHeaders = 0;       // a header with a good CRC but impossible fields
  std::uint64_t resyncs = 0;          // times the decoder had to hunt for the next magic
  std::uint64_t skippedBytes = 0;     // bytes thrown away while hunting
  std::uint64_t sequenceGaps = 0;     // frames missing between consecutive sequence numbers
  std::uint64_t frameBytes = 0;       // bytes of the frames handed out, headers included
  // Every byte fed is in exactly one place: bytesIn == frameBytes + skippedBytes + buffered().
};

class FrameDecoder {
public:
  using OnFrame = std::function<void(WireFrame&&)>;
  explicit FrameDecoder(DecoderLimits limits = {});

  // Takes the next bytes of the stream; calls onFrame for each frame that
  // completes with both CRCs good, in order.
  void feed(std::span<const std::uint8_t> bytes, const OnFrame& onFrame);
  // Forgets any partial frame (after a reconnect or a device reset). The next
  // frame's sequence number is then not counted as a gap.
  void reset();

  const DecoderCounters& counters() const { return counters_; }
  // Bytes held for a frame not yet complete (bounded by header + max payload).
  std::size_t buffered() const;

private:
  enum class State : std::uint8_t { Hunt, Header, Payload };
  enum class Event : std::uint8_t { None, Frame, Rejected };
  // Consumes bytes of the logical stream until they run out or the current
  // candidate frame completes (into done_) or is rejected; returns how many it took.
  std::size_t step(const std::uint8_t* p, std::size_t n, Event& ev);
  std::size_t hunt(const std::uint8_t* p, std::size_t n);
  bool parseHeader();  // false: rejected (counted)
  void complete();
  void reject();
  void discard(std::size_t n);
  void requeueCandidate();

  DecoderLimits limits_;
  DecoderCounters counters_;
  // Bytes to be parsed again before the caller's next bytes: a rejected
  // candidate's bytes after its magic (plus any replay it had not reached).
  std::vector<std::uint8_t> buf_;
  std::size_t start_ = 0;  // first unparsed byte of buf_
  bool haveSeq_ = false;
  std::uint32_t lastSeq_ = 0;

  State state_ = State::Hunt;
  bool hunting_ = false;  // inside a hunt already counted in resyncs
  std::array<std::uint8_t, kHeaderBytes> hdr_{};
  std::size_t hdrFill_ = 0;  // magic (partial while hunting) and header bytes held in hdr_
  WireFrame cur_;            // the candidate's header fields; its pixels fill as the payload arrives
  WireFrame done_;           // a completed frame on its way to onFrame
  std::uint32_t payloadBytes_ = 0, payloadCrc_ = 0, expectedCrc_ = 0;
};

}  // namespace pp5::board
