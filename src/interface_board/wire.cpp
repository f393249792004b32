// The interface board's wire format and its resynchronising decoder.
//
// One frame on the wire is a 160-byte header followed by the payload (the
// pixel rows, width * height * bytesPerPixel bytes, 16-bit pixels
// little-endian). Every multi-byte field is little-endian and is written and
// read one byte at a time, so the format does not depend on the host.
//
//   offset  size  type      field
//   ------  ----  --------  ------------------------------------------------
//        0     4  u32       magic 0x46354850 (the bytes "PH5F")
//        4     2  u16       version, 1
//        6     2  u16       headerBytes, 160
//        8     4  u32       sequence: +1 per frame sent, wraps at 2^32
//       12     4  u32       flags: bit 0 image invalid, bit 1 pose invalid, bit 2 end of stream
//       16     8  u64       timestampUs: the board's clock at capture
//       24     2  u16       width, pixels (1..4096 by default)
//       26     2  u16       height, pixels (1..4096 by default)
//       28     1  u8        bytesPerPixel, 1 or 2
//       29     1  u8        poseKind: 0 none, 1 arm counts, 2 matrix
//       30     2  u16       reserved, 0
//       32     4  u32       payloadBytes = width * height * bytesPerPixel
//       36     6  3 x u16   armCounts x, y, theta (0..4095; 0 unless poseKind 1)
//       42     2  u16       reserved, 0
//       44    96  12 x f64  matrix: ProbeToTracker rows 0..2, row-major, mm,
//                           IEEE 754 binary64 bits (0 unless poseKind 2)
//      140    12            zero padding
//      152     4  u32       payloadCrc: CRC-32 of the payload
//      156     4  u32       headerCrc: CRC-32 of bytes 0..155
//
// CRC-32 is IEEE 802.3's (zlib's crc32). Readers ignore the reserved fields
// and the padding, so a later version-1 board may use them.
#include "interface_board/wire.hpp"

#include <algorithm>
#include <bit>
#include <cstring>
#include <limits>

#include <zlib.h>

#include "core/error.hpp"

namespace pp5::board {

namespace {

constexpr std::size_t kOffVersion = 4, kOffHeaderBytes = 6, kOffSequence = 8, kOffFlags = 12, kOffTimestamp = 16,
                      kOffWidth = 24, kOffHeight = 26, kOffBpp = 28, kOffPoseKind = 29, kOffPayloadBytes = 32,
                      kOffArmCounts = 36, kOffMatrix = 44, kOffPayloadCrc = 152, kOffHeaderCrc = 156;
constexpr std::size_t kMagicBytes = 4;
constexpr std::uint8_t kMagicByte[kMagicBytes] = {kMagic & 0xFF, (kMagic >> 8) & 0xFF, (kMagic >> 16) & 0xFF,
                                                   kMagic >> 24};
constexpr std::uint16_t kMaxArmCount = 4095;

template <typename T>
void put(std::uint8_t* h, std::size_t off, T v) {
  for (std::size_t i = 0; i < sizeof(T); ++i) h[off + i] = static_cast<std::uint8_t>(v >> (8 * i));
}
template <typename T>
T get(const std::uint8_t* h, std::size_t off) {
  T v = 0;
  for (std::size_t i = 0; i < sizeof(T); ++i) v = static_cast<T>(v | static_cast<T>(h[off + i]) << (8 * i));
  return v;
}

}  // namespace

std::uint32_t crc32(std::span<const std::uint8_t> bytes, std::uint32_t crc) {
  // zlib takes a 32-bit length; feed larger spans in pieces.
  const std::uint8_t* p = bytes.data();
  std::size_t n = bytes.size();
  uLong c = crc;
  while (n > 0) {
    const auto take = static_cast<uInt>(std::min<std::size_t>(n, std::numeric_limits<uInt>::max()));
    c = ::crc32(c, p, take);
    p += take;
    n -= take;
  }
  return static_cast<std::uint32_t>(c);
}

void encodeFrame(const WireFrame& f, std::vector<std::uint8_t>& out) {
  if (f.bytesPerPixel != 1 && f.bytesPerPixel != 2)
    throw InputError(fmt::format("wire frame {}: bytes per pixel is {}, must be 1 or 2", f.sequence,
                                 static_cast<int>(f.bytesPerPixel)));
  if (f.width == 0 || f.height == 0)
    throw InputError(fmt::format("wire frame {}: the image is {}x{}, it must have at least one pixel", f.sequence,
                                 f.width, f.height));
  const std::uint64_t payload = std::uint64_t{f.width} * f.height * f.bytesPerPixel;
  if (payload > std::numeric_limits<std::uint32_t>::max())
    throw InputError(fmt::format("wire frame {}: {} payload bytes do not fit the 32-bit length", f.sequence, payload));
  if (f.pixels.size() != payload)
    throw InputError(fmt::format("wire frame {}: {} pixel bytes for a {}x{} image of {} byte(s) per pixel ({} expected)",
                                 f.sequence, f.pixels.size(), f.width, f.height, static_cast<int>(f.bytesPerPixel),
                                 payload));
  const auto kind = static_cast<std::uint8_t>(f.poseKind);
  if (kind > static_cast<std::uint8_t>(PoseKind::Matrix))
    throw InputError(fmt::format("wire frame {}: unknown pose kind {}", f.sequence, static_cast<int>(kind)));
  if (f.poseKind == PoseKind::ArmCounts)
    for (std::size_t i = 0; i < 3; ++i)
      if (f.armCounts[i] > kMaxArmCount)
        throw InputError(fmt::format("wire frame {}: arm count {} is {}, over the 12-bit A/D's {}", f.sequence, i,
                                     f.armCounts[i], kMaxArmCount));

  std::array<std::uint8_t, kHeaderBytes> h{};
  put<std::uint32_t>(h.data(), 0, kMagic);
  put<std::uint16_t>(h.data(), kOffVersion, kVersion);
  put<std::uint16_t>(h.data(), kOffHeaderBytes, static_cast<std::uint16_t>(kHeaderBytes));
  put<std::uint32_t>(h.data(), kOffSequence, f.sequence);
  put<std::uint32_t>(h.data(), kOffFlags, f.flags);
  put<std::uint64_t>(h.data(), kOffTimestamp, f.timestampUs);
  put<std::uint16_t>(h.data(), kOffWidth, f.width);
  put<std::uint16_t>(h.data(), kOffHeight, f.height);
  h[kOffBpp] = f.bytesPerPixel;
  h[kOffPoseKind] = kind;
  put<std::uint32_t>(h.data(), kOffPayloadBytes, static_cast<std::uint32_t>(payload));
  // Fields that the pose kind does not use stay zero, so decode(encode(f)) is canonical.
  if (f.poseKind == PoseKind::ArmCounts)
    for (std::size_t i = 0; i < 3; ++i) put<std::uint16_t>(h.data(), kOffArmCounts + 2 * i, f.armCounts[i]);
  if (f.poseKind == PoseKind::Matrix)
    for (std::size_t i = 0; i < 12; ++i)
      put<std::uint64_t>(h.data(), kOffMatrix + 8 * i, std::bit_cast<std::uint64_t>(f.matrix[i]));
  put<std::uint32_t>(h.data(), kOffPayloadCrc, crc32(f.pixels));
  put<std::uint32_t>(h.data(), kOffHeaderCrc, crc32(std::span(h.data(), kOffHeaderCrc)));

  out.reserve(out.size() + kHeaderBytes + f.pixels.size());
  out.insert(out.end(), h.begin(), h.end());
  out.insert(out.end(), f.pixels.begin(), f.pixels.end());
}

// ---- decoder ----------------------------------------------------------------------
//
// The stream is parsed as one logical sequence: first the replay buffer (buf_
// from start_), then the caller's bytes. A candidate frame's bytes are copied
// once, the header into hdr_ and the payload straight into the pixel vector
// it will be handed out in. When a candidate is rejected (bad header CRC,
// impossible fields, bad payload CRC), everything after its magic goes back
// to the front of the replay buffer: a frame the board cut short is followed
// at once by the next frame, whose header then lies inside what was taken
// for this frame's payload.
//
// Memory: bytes move between the replay buffer and the candidate, and the
// candidate grows only up to a validated header plus its payload, so the
// total stays within kHeaderBytes + maxPayloadBytes.
//
// Cost: a payload whose CRC fails is parsed again. A crafted stream of nested
// headers with good CRCs could make that quadratic; real faults (noise, lost
// packets, cut frames) rescan each byte a bounded number of times.

FrameDecoder::FrameDecoder(DecoderLimits limits) : limits_(limits) {}

std::size_t FrameDecoder::buffered() const { return (buf_.size() - start_) + hdrFill_ + cur_.pixels.size(); }

void FrameDecoder::reset() {
  counters_.skippedBytes += buffered();  // dropped, so the byte accounting still balances
  buf_.clear();
  buf_.shrink_to_fit();
  start_ = 0;
  state_ = State::Hunt;
  hunting_ = false;
  hdrFill_ = 0;
  cur_ = WireFrame{};
  haveSeq_ = false;
}

void FrameDecoder::feed(std::span<const std::uint8_t> bytes, const OnFrame& onFrame) {
  counters_.bytesIn += bytes.size();
  const std::uint8_t* p = bytes.data();
  std::size_t n = bytes.size();
  for (;;) {
    Event ev = Event::None;
    if (start_ < buf_.size()) {
      start_ += step(buf_.data() + start_, buf_.size() - start_, ev);
      if (start_ == buf_.size() && ev != Event::Rejected) {
        buf_.clear();
        start_ = 0;
      }
    } else if (n > 0) {
      const std::size_t used = step(p, n, ev);
      p += used;
      n -= used;
    } else {
      break;
    }
    if (ev == Event::Rejected) requeueCandidate();
    if (ev == Event::Frame) {
      try {
        onFrame(std::move(done_));
      } catch (...) {
        // Keep the rest of this feed for the next call, so that a consumer's
        // error loses no frame (buffered() then exceeds its bound by those bytes).
        buf_.insert(buf_.end(), p, p + n);
        throw;
      }
    }
  }
}

void FrameDecoder::requeueCandidate() {
  // New replay = candidate after its magic, then the replay not yet reached.
  std::vector<std::uint8_t> next;
  next.reserve(hdrFill_ - kMagicBytes + cur_.pixels.size() + (buf_.size() - start_));
  next.insert(next.end(), hdr_.begin() + kMagicBytes, hdr_.begin() + static_cast<std::ptrdiff_t>(hdrFill_));
  next.insert(next.end(), cur_.pixels.begin(), cur_.pixels.end());
  next.insert(next.end(), buf_.begin() + static_cast<std::ptrdiff_t>(start_), buf_.end());
  buf_.swap(next);
  start_ = 0;
  hdrFill_ = 0;
  cur_.pixels.clear();
}

void FrameDecoder::discard(std::size_t n) {
  if (n == 0) return;
  counters_.skippedBytes += n;
  if (!hunting_) {
    hunting_ = true;
    ++counters_.resyncs;
  }
}

void FrameDecoder::reject() {
  // The magic is dropped; the caller re-parses the rest (requeueCandidate).
  counters_.skippedBytes += kMagicBytes;
  ++counters_.resyncs;
  hunting_ = true;
  state_ = State::Hunt;
}

std::size_t FrameDecoder::hunt(const std::uint8_t* p, std::size_t n) {
  std::size_t i = 0;
  // A magic begun at the end of the previous bytes. Its first byte occurs
  // nowhere else in it, so on a mismatch no held byte can start a magic.
  while (hdrFill_ > 0 && i < n) {
    if (p[i] != kMagicByte[hdrFill_]) {
      discard(hdrFill_);
      hdrFill_ = 0;
      break;
    }
    hdr_[hdrFill_++] = p[i++];
    if (hdrFill_ == kMagicBytes) {
      hunting_ = false;
      state_ = State::Header;
      return i;
    }
  }
  while (i < n) {
    const auto* q = static_cast<const std::uint8_t*>(std::memchr(p + i, kMagicByte[0], n - i));
    if (!q) {
      discard(n - i);
      return n;
    }
    const auto j = static_cast<std::size_t>(q - p);
    discard(j - i);
    i = j;
    std::size_t m = 1;
    while (m < kMagicBytes && i + m < n && p[i + m] == kMagicByte[m]) ++m;
    if (m == kMagicBytes || i + m == n) {  // a whole magic, or a prefix that the next bytes may finish
      std::memcpy(hdr_.data(), p + i, m);
      hdrFill_ = m;
      if (m == kMagicBytes) {
        hunting_ = false;
        state_ = State::Header;
      }
      return i + m;
    }
    discard(1);
    ++i;
  }
  return n;
}

bool FrameDecoder::parseHeader() {
  const std::uint8_t* h = hdr_.data();
  if (crc32(std::span(h, kOffHeaderCrc)) != get<std::uint32_t>(h, kOffHeaderCrc)) {
    ++counters_.headerCrcErrors;
    return false;
  }
  WireFrame& f = cur_;
  f.sequence = get<std::uint32_t>(h, kOffSequence);
  f.flags = get<std::uint32_t>(h, kOffFlags);
  f.timestampUs = get<std::uint64_t>(h, kOffTimestamp);
  f.width = get<std::uint16_t>(h, kOffWidth);
  f.height = get<std::uint16_t>(h, kOffHeight);
  f.bytesPerPixel = h[kOffBpp];
  const std::uint8_t kind = h[kOffPoseKind];
  payloadBytes_ = get<std::uint32_t>(h, kOffPayloadBytes);
  bool ok = get<std::uint16_t>(h, kOffVersion) == kVersion && get<std::uint16_t>(h, kOffHeaderBytes) == kHeaderBytes &&
            (f.bytesPerPixel == 1 || f.bytesPerPixel == 2) && kind <= static_cast<std::uint8_t>(PoseKind::Matrix) &&
            f.width >= 1 && f.width <= limits_.maxWidth && f.height >= 1 && f.height <= limits_.maxHeight &&
            payloadBytes_ == std::uint64_t{f.width} * f.height * f.bytesPerPixel &&
            payloadBytes_ <= limits_.maxPayloadBytes;
  f.poseKind = static_cast<PoseKind>(kind);
  f.armCounts = {};
  f.matrix = {};
  if (ok && f.poseKind == PoseKind::ArmCounts)
    for (std::size_t i = 0; i < 3; ++i) {
      f.armCounts[i] = get<std::uint16_t>(h, kOffArmCounts + 2 * i);
      ok = ok && f.armCounts[i] <= kMaxArmCount;
    }
  if (ok && f.poseKind == PoseKind::Matrix)
    for (std::size_t i = 0; i < 12; ++i) f.matrix[i] = std::bit_cast<double>(get<std::uint64_t>(h, kOffMatrix + 8 * i));
  if (!ok) {
    ++counters_.badHeaders;
    return false;
  }
  expectedCrc_ = get<std::uint32_t>(h, kOffPayloadCrc);
  payloadCrc_ = 0;
  // Only now, with the length validated against the limits, is memory taken.
  cur_.pixels.clear();
  cur_.pixels.reserve(payloadBytes_);
  return true;
}

void FrameDecoder::complete() {
  done_ = std::move(cur_);
  cur_ = WireFrame{};
  if (haveSeq_) {
    // A jump of half the sequence space or more is a board that restarted its
    // numbering (or a repeat), not four billion lost frames.
    const std::uint32_t gap = done_.sequence - lastSeq_ - 1u;
    if (gap < 0x80000000u) counters_.sequenceGaps += gap;
  }
  haveSeq_ = true;
  lastSeq_ = done_.sequence;
  ++counters_.frames;
  counters_.frameBytes += kHeaderBytes + payloadBytes_;
  hdrFill_ = 0;
  state_ = State::Hunt;
}

std::size_t FrameDecoder::step(const std::uint8_t* p, std::size_t n, Event& ev) {
  switch (state_) {
  case State::Hunt:
    return hunt(p, n);
  case State::Header: {
    const std::size_t take = std::min(n, kHeaderBytes - hdrFill_);
    std::memcpy(hdr_.data() + hdrFill_, p, take);
    hdrFill_ += take;
    if (hdrFill_ == kHeaderBytes) {
      if (parseHeader()) {
        state_ = State::Payload;
      } else {
        reject();
        ev = Event::Rejected;
      }
    }
    return take;
  }
  case State::Payload: {
    auto& px = cur_.pixels;
    const std::size_t take = std::min<std::size_t>(n, payloadBytes_ - px.size());
    px.insert(px.end(), p, p + take);
    payloadCrc_ = crc32(std::span(p, take), payloadCrc_);
    if (px.size() == payloadBytes_) {
      if (payloadCrc_ == expectedCrc_) {
        complete();
        ev = Event::Frame;
      } else {
        ++counters_.payloadCrcErrors;
        reject();
        ev = Event::Rejected;
      }
    }
    return take;
  }
  }
  return n;
}

}  // namespace pp5::board
