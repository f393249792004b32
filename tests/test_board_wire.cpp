// The interface board's wire format, its resynchronising decoder and the
// arm's calibration.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "core/error.hpp"
#include "interface_board/arm_calibration.hpp"
#include "interface_board/wire.hpp"
#include "sim/probe_motion.hpp"
#include "sim/sim_settings.hpp"

// The fuzz target's checks, so that the committed corpus replays here too.
#define PP5_FUZZ_NO_ENTRY
#include "fuzz/fuzz_decoder.cpp"

namespace {

using namespace pp5::board;
using Bytes = std::vector<std::uint8_t>;

WireFrame randomFrame(std::mt19937& rng, std::uint32_t seq, int maxSide = 40) {
  std::uniform_int_distribution<int> side(1, maxSide), byte(0, 255), kind(0, 2), count(0, 4095);
  WireFrame f;
  f.sequence = seq;
  f.timestampUs = (std::uint64_t{rng()} << 32) | rng();
  f.width = static_cast<std::uint16_t>(side(rng));
  f.height = static_cast<std::uint16_t>(side(rng));
  f.bytesPerPixel = static_cast<std::uint8_t>(1 + rng() % 2);
  f.poseKind = static_cast<PoseKind>(kind(rng));
  f.flags = rng() % 4;
  if (f.poseKind == PoseKind::ArmCounts)
    for (auto& c : f.armCounts) c = static_cast<std::uint16_t>(count(rng));
  if (f.poseKind == PoseKind::Matrix)
    for (auto& m : f.matrix) m = std::uniform_real_distribution<double>(-500.0, 500.0)(rng);
  f.pixels.resize(std::size_t{f.width} * f.height * f.bytesPerPixel);
  for (auto& p : f.pixels) p = static_cast<std::uint8_t>(byte(rng));
  return f;
}

WireFrame plainFrame(std::uint32_t seq, std::uint16_t w, std::uint16_t h) {
  WireFrame f;
  f.sequence = seq;
  f.width = w;
  f.height = h;
  f.pixels.resize(std::size_t{w} * h);
  for (std::size_t i = 0; i < f.pixels.size(); ++i) f.pixels[i] = static_cast<std::uint8_t>(i * 7 + seq);
  return f;
}

Bytes encode(const WireFrame& f) {
  Bytes b;
  encodeFrame(f, b);
  return b;
}
Bytes encodeAll(const std::vector<WireFrame>& fs) {
  Bytes b;
  for (const auto& f : fs) encodeFrame(f, b);
  return b;
}
void append(Bytes& a, const Bytes& b) { a.insert(a.end(), b.begin(), b.end()); }

// Rewrites header fields and re-signs the header, so that only the fields are wrong.
void patchHeader(Bytes& b, std::size_t off, const Bytes& v) {
  std::copy(v.begin(), v.end(), b.begin() + static_cast<std::ptrdiff_t>(off));
  const std::uint32_t c = crc32(std::span(b.data(), 156));
  for (int i = 0; i < 4; ++i) b[156 + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(c >> (8 * i));
}

std::uint32_t le32(const Bytes& b, std::size_t off) {
  return b[off] | b[off + 1] << 8 | b[off + 2] << 16 | std::uint32_t{b[off + 3]} << 24;
}

struct Decoded {
  std::vector<WireFrame> frames;
  FrameDecoder::OnFrame sink() {
    return [this](WireFrame&& f) { frames.push_back(std::move(f)); };
  }
  std::vector<std::uint32_t> sequences() const {
    std::vector<std::uint32_t> s;
    for (const auto& f : frames) s.push_back(f.sequence);
    return s;
  }
};

void expectSameFrames(const std::vector<WireFrame>& got, const std::vector<WireFrame>& want) {
  ASSERT_EQ(got.size(), want.size());
  for (std::size_t i = 0; i < want.size(); ++i)
    EXPECT_TRUE(pp5::fuzz::sameFrame(got[i], want[i])) << "frame " << i << " (sequence " << want[i].sequence << ")";
}

void expectBalanced(const FrameDecoder& d) {
  const auto& c = d.counters();
  EXPECT_EQ(c.bytesIn, c.frameBytes + c.skippedBytes + d.buffered());
}

// ---- the format -----------------------------------------------------------------------

TEST(BoardWire, Crc32IsIeee) {
  const std::string s = "123456789";
  EXPECT_EQ(crc32({reinterpret_cast<const std::uint8_t*>(s.data()), s.size()}), 0xCBF43926u);
  // Incremental equals one pass.
  const auto* p = reinterpret_cast<const std::uint8_t*>(s.data());
  EXPECT_EQ(crc32({p + 4, 5}, crc32({p, 4})), 0xCBF43926u);
}

TEST(BoardWire, HeaderLayoutByteByByte) {
  WireFrame f = plainFrame(0x01020304u, 3, 2);
  f.bytesPerPixel = 2;
  f.pixels.assign(12, 0xAB);
  f.flags = kFlagPoseInvalid;
  f.timestampUs = 0x1122334455667788ull;
  f.poseKind = PoseKind::Matrix;
  f.matrix[0] = 1.0;
  f.matrix[11] = -2.5;
  const Bytes b = encode(f);
  ASSERT_EQ(b.size(), kHeaderBytes + 12);
  EXPECT_EQ((Bytes{b.begin(), b.begin() + 4}), (Bytes{'P', 'H', '5', 'F'}));
  EXPECT_EQ(b[4], 1);
  EXPECT_EQ(b[5], 0);
  EXPECT_EQ(b[6], 160);
  EXPECT_EQ(b[7], 0);
  EXPECT_EQ((Bytes{b.begin() + 8, b.begin() + 12}), (Bytes{4, 3, 2, 1}));
  EXPECT_EQ(le32(b, 12), kFlagPoseInvalid);
  EXPECT_EQ((Bytes{b.begin() + 16, b.begin() + 24}), (Bytes{0x88, 0x77, 0x66, 0x55, 0x44, 0x33, 0x22, 0x11}));
  EXPECT_EQ(b[24], 3);
  EXPECT_EQ(b[26], 2);
  EXPECT_EQ(b[28], 2);
  EXPECT_EQ(b[29], 2);
  EXPECT_EQ(le32(b, 32), 12u);
  for (std::size_t i = 36; i < 44; ++i) EXPECT_EQ(b[i], 0) << i;  // no arm counts for a matrix pose
  const auto one = std::bit_cast<std::uint64_t>(1.0), last = std::bit_cast<std::uint64_t>(-2.5);
  for (std::size_t i = 0; i < 8; ++i) {
    EXPECT_EQ(b[44 + i], static_cast<std::uint8_t>(one >> (8 * i)));
    EXPECT_EQ(b[44 + 88 + i], static_cast<std::uint8_t>(last >> (8 * i)));
  }
  for (std::size_t i = 140; i < 152; ++i) EXPECT_EQ(b[i], 0) << i;
  EXPECT_EQ(le32(b, 152), crc32(std::span(b.data() + 160, 12)));
  EXPECT_EQ(le32(b, 156), crc32(std::span(b.data(), 156)));

  WireFrame arm = plainFrame(1, 1, 1);
  arm.poseKind = PoseKind::ArmCounts;
  arm.armCounts = {0x0123, 4095, 7};
  const Bytes a = encode(arm);
  EXPECT_EQ((Bytes{a.begin() + 36, a.begin() + 42}), (Bytes{0x23, 0x01, 0xFF, 0x0F, 7, 0}));
}

TEST(BoardWire, EncodeRefusesInconsistentFrames) {
  auto refused = [](WireFrame f) {
    Bytes out;
    EXPECT_THROW(encodeFrame(f, out), pp5::InputError);
    EXPECT_TRUE(out.empty());
  };
  WireFrame f = plainFrame(1, 4, 3);
  f.pixels.pop_back();
  refused(f);
  f = plainFrame(1, 4, 3);
  f.bytesPerPixel = 3;
  refused(f);
  f = plainFrame(1, 4, 3);
  f.bytesPerPixel = 2;  // 12 bytes for 24
  refused(f);
  f = plainFrame(1, 4, 3);
  f.poseKind = PoseKind::ArmCounts;
  f.armCounts = {0, 4096, 0};
  refused(f);
  f = plainFrame(1, 4, 3);
  f.poseKind = static_cast<PoseKind>(3);
  refused(f);
  refused(plainFrame(1, 0, 3));
  // Counts over 4095 do not matter when the pose is not arm counts.
  f = plainFrame(1, 4, 3);
  f.armCounts = {9999, 0, 0};
  Bytes out;
  EXPECT_NO_THROW(encodeFrame(f, out));
}

// ---- whole streams ----------------------------------------------------------------------

TEST(BoardWire, RoundTripRandomFrames) {
  std::mt19937 rng(11);
  std::vector<WireFrame> frames;
  for (std::uint32_t i = 0; i < 300; ++i) frames.push_back(randomFrame(rng, 100 + i));
  const Bytes s = encodeAll(frames);
  FrameDecoder d;
  Decoded out;
  d.feed(s, out.sink());
  expectSameFrames(out.frames, frames);
  const auto& c = d.counters();
  EXPECT_EQ(c.frames, 300u);
  EXPECT_EQ(c.bytesIn, s.size());
  EXPECT_EQ(c.frameBytes, s.size());
  EXPECT_EQ(c.headerCrcErrors + c.payloadCrcErrors + c.badHeaders + c.resyncs + c.skippedBytes, 0u);
  EXPECT_EQ(c.sequenceGaps, 0u);
  EXPECT_EQ(d.buffered(), 0u);
  // Each kind, width and flag combination appeared.
  int kinds[3] = {}, u16 = 0;
  for (const auto& f : frames) {
    ++kinds[static_cast<int>(f.poseKind)];
    u16 += f.bytesPerPixel == 2;
  }
  EXPECT_GT(kinds[0] * kinds[1] * kinds[2], 0);
  EXPECT_GT(u16, 0);
}

TEST(BoardWire, EverySplitOfTwoFramesIntoTwoFeeds) {
  std::mt19937 rng(5);
  WireFrame a = randomFrame(rng, 7, 6), b = randomFrame(rng, 8, 6);
  a.bytesPerPixel = 2;
  a.pixels.resize(std::size_t{a.width} * a.height * 2, 0x50);  // 'P' bytes that are not a magic
  b.poseKind = PoseKind::ArmCounts;
  b.armCounts = {1, 2, 4095};
  const Bytes s = encodeAll({a, b});
  for (std::size_t k = 0; k <= s.size(); ++k) {
    FrameDecoder d;
    Decoded out;
    d.feed(std::span(s.data(), k), out.sink());
    d.feed(std::span(s.data() + k, s.size() - k), out.sink());
    SCOPED_TRACE("split at " + std::to_string(k));
    expectSameFrames(out.frames, {a, b});
    EXPECT_EQ(d.counters().resyncs + d.counters().skippedBytes, 0u);
    EXPECT_EQ(d.buffered(), 0u);
  }
}

TEST(BoardWire, RandomSplitsIncludingOneByteFeeds) {
  std::mt19937 rng(6);
  std::vector<WireFrame> frames;
  for (std::uint32_t i = 0; i < 60; ++i) frames.push_back(randomFrame(rng, i, 20));
  const Bytes s = encodeAll(frames);
  for (int trial = 0; trial < 20; ++trial) {
    FrameDecoder d;
    Decoded out;
    std::size_t pos = 0;
    // Trial 0 feeds one byte at a time; the others mix 0..3-byte and longer feeds.
    std::uniform_int_distribution<std::size_t> small(0, 3), large(0, 1500);
    while (pos < s.size()) {
      const std::size_t n = std::min(s.size() - pos, trial == 0 ? 1 : (rng() % 3 ? small(rng) : large(rng)));
      d.feed(std::span(s.data() + pos, n), out.sink());
      pos += n;
      ASSERT_LE(d.buffered(), kHeaderBytes + 20 * 20 * 2);
    }
    SCOPED_TRACE("trial " + std::to_string(trial));
    expectSameFrames(out.frames, frames);
    EXPECT_EQ(d.counters().frames, 60u);
    EXPECT_EQ(d.counters().resyncs, 0u);
    EXPECT_EQ(d.buffered(), 0u);
  }
}

// ---- faults ---------------------------------------------------------------------------

// Frames 1, 2, 3 of 16x8 pixels: kHeaderBytes + 128 bytes each.
std::vector<WireFrame> threeFrames() { return {plainFrame(1, 16, 8), plainFrame(2, 16, 8), plainFrame(3, 16, 8)}; }

// Of threeFrames(), the middle one was lost to one CRC error (in its header
// or its payload) and one resync, and nothing else.
void expectMiddleLostToCrc(const FrameDecoder& d, const Decoded& out, const std::vector<WireFrame>& f,
                           std::uint64_t headerCrcErrors, std::uint64_t payloadCrcErrors) {
  expectSameFrames(out.frames, {f[0], f[2]});
  const auto& c = d.counters();
  EXPECT_EQ(c.headerCrcErrors, headerCrcErrors);
  EXPECT_EQ(c.payloadCrcErrors, payloadCrcErrors);
  EXPECT_EQ(c.badHeaders, 0u);
  EXPECT_EQ(c.resyncs, 1u);
  EXPECT_EQ(c.skippedBytes, kHeaderBytes + 128);
  EXPECT_EQ(c.sequenceGaps, 1u);
  expectBalanced(d);
}

TEST(BoardWire, CorruptHeaderByteLosesOneFrame) {
  const std::vector<WireFrame> f = threeFrames();
  Bytes s = encodeAll(f);
  s[kHeaderBytes + 128 + 20] ^= 0x04;  // frame 2's timestamp
  FrameDecoder d;
  Decoded out;
  d.feed(s, out.sink());
  expectMiddleLostToCrc(d, out, f, 1, 0);
}

TEST(BoardWire, CorruptMagicLosesOneFrameWithoutCrcError) {
  const std::vector<WireFrame> f = threeFrames();
  Bytes s = encodeAll(f);
  s[kHeaderBytes + 128 + 2] ^= 0x01;
  FrameDecoder d;
  Decoded out;
  d.feed(s, out.sink());
  expectSameFrames(out.frames, {f[0], f[2]});
  EXPECT_EQ(d.counters().headerCrcErrors, 0u);
  EXPECT_EQ(d.counters().resyncs, 1u);
  EXPECT_EQ(d.counters().skippedBytes, kHeaderBytes + 128);
}

TEST(BoardWire, CorruptPayloadByteLosesOneFrame) {
  const std::vector<WireFrame> f = threeFrames();
  Bytes s = encodeAll(f);
  s[(kHeaderBytes + 128) + kHeaderBytes + 77] ^= 0x80;  // a byte of frame 2's pixels
  FrameDecoder d;
  Decoded out;
  for (std::size_t i = 0; i < s.size(); i += 100) d.feed(std::span(s.data() + i, std::min<std::size_t>(100, s.size() - i)), out.sink());
  expectMiddleLostToCrc(d, out, f, 0, 1);
}

TEST(BoardWire, DroppedPacketsLoseOnlyTheFramesTheyTouch) {
  // 30 frames of 64x32 u8 (2208 bytes each) sent as 512-byte packets.
  std::vector<WireFrame> f;
  std::mt19937 rng(3);
  for (std::uint32_t i = 0; i < 30; ++i) {
    WireFrame w = plainFrame(1000 + i, 64, 32);
    for (auto& p : w.pixels) p = static_cast<std::uint8_t>(rng());
    f.push_back(w);
  }
  const Bytes s = encodeAll(f);
  const std::size_t frameBytes = 2208, packet = 512;
  ASSERT_EQ(s.size(), 30 * frameBytes);
  // Packet 10 lies in frame 2's payload, 26 starts 64 bytes into frame 6's
  // header, 40-41 lie in frame 9's payload, and 64 takes frame 14's last 352
  // bytes and frame 15's whole header.
  const std::vector<std::size_t> dropped = {10, 26, 40, 41, 64};
  FrameDecoder d;
  Decoded out;
  for (std::size_t k = 0; k * packet < s.size(); ++k)
    if (std::find(dropped.begin(), dropped.end(), k) == dropped.end())
      d.feed(std::span(s.data() + k * packet, std::min(packet, s.size() - k * packet)), out.sink());
  std::vector<std::uint32_t> want;
  for (std::uint32_t i = 0; i < 30; ++i)
    if (i != 2 && i != 6 && i != 9 && i != 14 && i != 15) want.push_back(1000 + i);
  EXPECT_EQ(out.sequences(), want);
  for (const auto& w : out.frames) EXPECT_TRUE(pp5::fuzz::sameFrame(w, f[w.sequence - 1000]));
  const auto& c = d.counters();
  EXPECT_EQ(c.frames, 25u);
  EXPECT_EQ(c.payloadCrcErrors, 3u);
  EXPECT_EQ(c.headerCrcErrors, 1u);
  EXPECT_EQ(c.badHeaders, 0u);
  EXPECT_EQ(c.resyncs, 4u);
  EXPECT_EQ(c.sequenceGaps, 5u);
  EXPECT_EQ(c.skippedBytes, 5 * frameBytes - dropped.size() * packet);
  EXPECT_EQ(d.buffered(), 0u);
  expectBalanced(d);
}

TEST(BoardWire, FrameCutShortDoesNotHideTheNextFrame) {
  const std::vector<WireFrame> f = {plainFrame(1, 40, 30), plainFrame(2, 40, 30), plainFrame(3, 40, 30),
                                    plainFrame(4, 40, 30)};
  Bytes s = encode(f[0]);
  Bytes cut = encode(f[1]);
  cut.resize(kHeaderBytes + 100);  // the board stopped 100 bytes into the payload
  append(s, cut);
  append(s, encode(f[2]));
  append(s, encode(f[3]));
  FrameDecoder d;
  Decoded out;
  for (std::size_t i = 0; i < s.size(); i += 512) d.feed(std::span(s.data() + i, std::min<std::size_t>(512, s.size() - i)), out.sink());
  expectSameFrames(out.frames, {f[0], f[2], f[3]});
  const auto& c = d.counters();
  EXPECT_EQ(c.payloadCrcErrors, 1u);
  EXPECT_EQ(c.headerCrcErrors, 0u);
  EXPECT_EQ(c.resyncs, 1u);
  EXPECT_EQ(c.skippedBytes, kHeaderBytes + 100);
  EXPECT_EQ(c.sequenceGaps, 1u);
  EXPECT_EQ(d.buffered(), 0u);
}

TEST(BoardWire, FrameCutInsideItsHeader) {
  const std::vector<WireFrame> f = {plainFrame(1, 10, 10), plainFrame(2, 10, 10), plainFrame(3, 10, 10)};
  Bytes s = encode(f[0]);
  Bytes cut = encode(f[1]);
  cut.resize(70);
  append(s, cut);
  append(s, encode(f[2]));
  FrameDecoder d;
  Decoded out;
  for (std::uint8_t b : s) d.feed(std::span(&b, 1), out.sink());
  expectSameFrames(out.frames, {f[0], f[2]});
  EXPECT_EQ(d.counters().headerCrcErrors, 1u);
  EXPECT_EQ(d.counters().resyncs, 1u);
  EXPECT_EQ(d.counters().skippedBytes, 70u);
}

TEST(BoardWire, FourGigabyteHeaderIsRefusedWithoutAllocating) {
  Bytes bad = encode(plainFrame(1, 4, 4));
  bad.resize(kHeaderBytes);
  // 65535 x 65535 x 1: payloadBytes 0xFFFE0001, consistent, signed, over the limit.
  patchHeader(bad, 24, {0xFF, 0xFF, 0xFF, 0xFF, 1, 0, 0, 0, 0x01, 0x00, 0xFE, 0xFF});
  FrameDecoder d;
  Decoded out;
  d.feed(bad, out.sink());
  EXPECT_EQ(d.counters().badHeaders, 1u);
  EXPECT_EQ(d.counters().headerCrcErrors, 0u);
  EXPECT_LE(d.buffered(), kHeaderBytes);  // only the header's bytes, held for the rescan
  const WireFrame next = plainFrame(2, 4, 4);
  d.feed(encode(next), out.sink());
  expectSameFrames(out.frames, {next});
  EXPECT_EQ(d.counters().resyncs, 1u);
  EXPECT_EQ(d.counters().skippedBytes, kHeaderBytes);
  EXPECT_EQ(d.buffered(), 0u);
}

TEST(BoardWire, HeadersOverTheLimitsOrInconsistentAreBad) {
  DecoderLimits lim;
  lim.maxPayloadBytes = 1u << 20;
  lim.maxWidth = 1500;
  // Each patch keeps the header signed, so only the sanity checks can refuse it.
  struct Case {
    const char* what;
    std::size_t off;
    Bytes v;
  };
  const std::vector<Case> cases = {
      {"1400x1000 x 1 = 1.4 MB over 1 MiB", 24, {0x78, 0x05, 0xE8, 0x03, 1, 0, 0, 0, 0xC0, 0x5C, 0x15, 0x00}},
      {"width 1600 over 1500", 24, {0x40, 0x06, 1, 0, 1, 0, 0, 0, 0x40, 0x06, 0, 0}},
      {"width 0", 24, {0, 0, 4, 0, 1, 0, 0, 0, 0, 0, 0, 0}},
      {"version 2", 4, {2, 0}},
      {"header size 128", 6, {128, 0}},
      {"3 bytes per pixel", 28, {3}},
      {"pose kind 3", 29, {3}},
      {"payload length not w*h*bpp", 32, {17, 0, 0, 0}},
      {"arm count 4096", 29, {1, 0, 0, 16, 0, 0, 0, 0, 0, 0x00, 0x10}},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.what);
    Bytes s = encode(plainFrame(1, 4, 4));
    patchHeader(s, c.off, c.v);
    const WireFrame next = plainFrame(2, 4, 4);
    append(s, encode(next));
    FrameDecoder d(lim);
    Decoded out;
    d.feed(s, out.sink());
    expectSameFrames(out.frames, {next});
    EXPECT_EQ(d.counters().badHeaders, 1u);
    EXPECT_EQ(d.counters().headerCrcErrors, 0u);
    EXPECT_EQ(d.counters().skippedBytes, kHeaderBytes + 16);
  }
}

TEST(BoardWire, GarbageBetweenFrames) {
  const std::vector<WireFrame> f = {plainFrame(1, 8, 8), plainFrame(2, 8, 8), plainFrame(3, 8, 8),
                                    plainFrame(4, 8, 8)};
  const Bytes junk1 = {0x00, 0x50, 0x48, 0x35, 0x00, 0x50, 0x50, 0x48, 0xFF};  // partial magics
  const Bytes junk2(1000, 0x50);
  const Bytes fakeMagic = {0x50, 0x48, 0x35, 0x46, 1, 2, 3};  // a magic whose "header" fails its CRC
  Bytes s = junk1;
  append(s, encode(f[0]));
  append(s, junk2);
  append(s, encode(f[1]));
  append(s, fakeMagic);
  append(s, encode(f[2]));
  append(s, junk1);
  append(s, encode(f[3]));
  for (std::size_t chunk : {std::size_t{1}, std::size_t{3}, std::size_t{64}, s.size()}) {
    FrameDecoder d;
    Decoded out;
    for (std::size_t i = 0; i < s.size(); i += chunk) d.feed(std::span(s.data() + i, std::min(chunk, s.size() - i)), out.sink());
    SCOPED_TRACE("chunk " + std::to_string(chunk));
    expectSameFrames(out.frames, f);
    const auto& c = d.counters();
    EXPECT_EQ(c.resyncs, 4u);
    EXPECT_EQ(c.headerCrcErrors, 1u);  // the fake magic took the next header's bytes, then gave them back
    EXPECT_EQ(c.skippedBytes, 2 * junk1.size() + junk2.size() + fakeMagic.size());
    EXPECT_EQ(c.sequenceGaps, 0u);
    EXPECT_EQ(d.buffered(), 0u);
  }
}

TEST(BoardWire, SequenceGapsWrapAround) {
  FrameDecoder d;
  Decoded out;
  for (std::uint32_t seq : {0xFFFFFFFEu, 0xFFFFFFFFu, 0u, 1u}) d.feed(encode(plainFrame(seq, 2, 2)), out.sink());
  EXPECT_EQ(d.counters().frames, 4u);
  EXPECT_EQ(d.counters().sequenceGaps, 0u);
  d.feed(encode(plainFrame(5, 2, 2)), out.sink());  // 2, 3, 4 missing
  EXPECT_EQ(d.counters().sequenceGaps, 3u);
  FrameDecoder w;
  w.feed(encode(plainFrame(0xFFFFFFFDu, 2, 2)), out.sink());
  w.feed(encode(plainFrame(1u, 2, 2)), out.sink());  // FFFFFFFE, FFFFFFFF, 0 missing
  EXPECT_EQ(w.counters().sequenceGaps, 3u);
}

TEST(BoardWire, ResetDropsThePartialFrameAndTheSequence) {
  FrameDecoder d;
  Decoded out;
  d.feed(encode(plainFrame(10, 8, 8)), out.sink());
  const Bytes half = encode(plainFrame(11, 8, 8));
  d.feed(std::span(half.data(), 100), out.sink());
  EXPECT_EQ(d.buffered(), 100u);
  d.reset();
  EXPECT_EQ(d.buffered(), 0u);
  // The board restarted: sequence 0 after 10 is no gap, and the rest of the
  // cut frame is never glued onto the old half.
  d.feed(std::span(half.data() + 100, half.size() - 100), out.sink());
  d.feed(encode(plainFrame(0, 8, 8)), out.sink());
  d.feed(encode(plainFrame(1, 8, 8)), out.sink());
  EXPECT_EQ(out.sequences(), (std::vector<std::uint32_t>{10, 0, 1}));
  EXPECT_EQ(d.counters().sequenceGaps, 0u);
  EXPECT_EQ(d.counters().skippedBytes, half.size());  // 100 dropped by reset, the rest skipped
  EXPECT_EQ(d.counters().resyncs, 1u);
  expectBalanced(d);
}

TEST(BoardWire, ResetDuringARescan) {
  // A cut frame leaves bytes queued for the rescan; reset drops those too.
  Bytes s = encode(plainFrame(1, 30, 30));
  s.resize(kHeaderBytes + 10);
  append(s, encode(plainFrame(2, 10, 10)));  // shorter than the 890 bytes still claimed
  FrameDecoder d;
  Decoded out;
  d.feed(s, out.sink());
  EXPECT_EQ(out.frames.size(), 0u);  // frame 2 lies inside frame 1's claimed payload
  EXPECT_GT(d.buffered(), 0u);
  d.reset();
  EXPECT_EQ(d.buffered(), 0u);
  expectBalanced(d);
  d.feed(encode(plainFrame(3, 30, 30)), out.sink());
  EXPECT_EQ(out.sequences(), (std::vector<std::uint32_t>{3}));
}

TEST(BoardWire, ThrowingCallbackLeavesTheDecoderUsable) {
  const std::vector<WireFrame> f = {plainFrame(1, 8, 8), plainFrame(2, 8, 8), plainFrame(3, 8, 8)};
  const Bytes s = encodeAll(f);
  FrameDecoder d;
  std::vector<std::uint32_t> seen;
  auto sink = [&](WireFrame&& w) {
    seen.push_back(w.sequence);
    if (w.sequence == 1) throw std::runtime_error("consumer failed");
  };
  EXPECT_THROW(d.feed(std::span(s.data(), kHeaderBytes + 64 + 10), sink), std::runtime_error);
  // The 10 bytes after frame 1 in that feed are kept; the stream carries on.
  EXPECT_EQ(d.counters().frames, 1u);
  EXPECT_EQ(d.buffered(), 10u);
  expectBalanced(d);
  d.feed(std::span(s.data() + kHeaderBytes + 64 + 10, s.size() - kHeaderBytes - 64 - 10), sink);
  EXPECT_EQ(seen, (std::vector<std::uint32_t>{1, 2, 3}));
  EXPECT_EQ(d.counters().resyncs, 0u);
  expectBalanced(d);
}

TEST(BoardWire, MemoryStaysBoundedOnHostileInput) {
  DecoderLimits lim;
  lim.maxPayloadBytes = 4096;
  FrameDecoder d(lim);
  Decoded out;
  std::mt19937 rng(9);
  // Signed headers claiming the largest payload allowed, each followed by noise and magics.
  Bytes s;
  for (int i = 0; i < 200; ++i) {
    Bytes h = encode(plainFrame(static_cast<std::uint32_t>(i), 64, 64));
    h.resize(kHeaderBytes);
    append(s, h);
    for (int k = 0; k < 700; ++k) s.push_back(k % 97 == 0 ? 0x50 : static_cast<std::uint8_t>(rng()));
  }
  for (std::size_t i = 0; i < s.size(); i += 333) {
    d.feed(std::span(s.data() + i, std::min<std::size_t>(333, s.size() - i)), out.sink());
    ASSERT_LE(d.buffered(), kHeaderBytes + lim.maxPayloadBytes);
  }
  EXPECT_EQ(out.frames.size(), 0u);
  EXPECT_GT(d.counters().payloadCrcErrors, 0u);
  expectBalanced(d);
}

// ---- the fuzz corpus --------------------------------------------------------------------

TEST(BoardWire, FuzzCorpusReplays) {
  const std::filesystem::path dir = std::filesystem::path(PP5_SOURCE_DIR) / "tests/fuzz/corpus";
  ASSERT_TRUE(std::filesystem::is_directory(dir)) << dir;
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    std::ifstream in(e.path(), std::ios::binary);
    const Bytes data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_NO_THROW(pp5::fuzz::checkDecoderInput(data.data(), data.size())) << e.path();
    ++n;
  }
  EXPECT_GE(n, 20);
}

// ---- the arm's calibration ------------------------------------------------------------

TEST(ArmCalibration, FromSimMatchesTheSimulatorsConverters) {
  pp5::sim::ArmSettings s;
  s.xSpanMm = 410.0;
  s.ySpanMm = 290.0;
  s.thetaSpanDeg = 170.0;
  s.referenceToTrackerMm = {190.0, 140.0, 5.0};
  const pp5::ArmAdc adc = pp5::sim::armAdc(s);
  const ArmCalibration cal = ArmCalibration::linear(pp5::sim::armAdc(s), s.referenceToTrackerMm, 42.0);
  EXPECT_NO_THROW(cal.validate());
  std::mt19937 rng(2);
  for (int i = 0; i < 2000; ++i) {
    const std::array<std::uint16_t, 3> c = {static_cast<std::uint16_t>(rng() % 4096),
                                            static_cast<std::uint16_t>(rng() % 4096),
                                            static_cast<std::uint16_t>(i < 3 ? i * 2047 : rng() % 4096)};
    const auto want = adc.calibrate({double(c[0]), double(c[1]), double(c[2])});
    const auto got = cal.toArmPose(c);
    ASSERT_NEAR(got.xMm, want.xMm, 1e-9);
    ASSERT_NEAR(got.yMm, want.yMm, 1e-9);
    ASSERT_NEAR(got.thetaDeg, want.thetaDeg, 1e-9);
    const pp5::Mat4 m = cal.probeToTracker(c), w = pp5::armProbeToTracker(want, 42.0);
    for (int col = 0; col < 4; ++col)
      for (int row = 0; row < 4; ++row) ASSERT_NEAR(m[col][row], w[col][row], 1e-9);
  }
  // Theta's zero sits on count 2048, as the simulator's converter has it.
  EXPECT_NEAR(cal.toArmPose(std::array<std::uint16_t, 3>{0, 0, 2048}).thetaDeg, 0.0, 1e-12);
  EXPECT_EQ(cal.referenceToTrackerMm, s.referenceToTrackerMm);
  EXPECT_EQ(cal.referenceToTracker()[3], pp5::Vec4(190.0, 140.0, 5.0, 1.0));
}

TEST(ArmCalibration, PiecewiseLinearInterpolatesAndExtrapolates) {
  ArmCalibration cal;
  cal.table[0] = parseArmTable({"100 10", "1100 60", "  3100\t260 "}, 0, "board.arm.x_table");
  cal.table[1] = {{0.0, 0.0}, {4095.0, 300.0}};
  cal.table[2] = parseArmTable({"0 -90", "2048 0", "4095 95"}, 2, "board.arm.theta_table");
  cal.validate();
  EXPECT_DOUBLE_EQ(cal.value(0, 100), 10.0);
  EXPECT_DOUBLE_EQ(cal.value(0, 600), 35.0);     // first segment, 0.05 mm/count
  EXPECT_DOUBLE_EQ(cal.value(0, 1100), 60.0);
  EXPECT_DOUBLE_EQ(cal.value(0, 2100), 160.0);   // second segment, 0.1 mm/count
  EXPECT_DOUBLE_EQ(cal.value(0, 0), 5.0);        // below: the first segment extended
  EXPECT_DOUBLE_EQ(cal.value(0, 4095), 359.5);   // above: the last segment extended
  EXPECT_DOUBLE_EQ(cal.value(2, 1024), -45.0);
  EXPECT_DOUBLE_EQ(cal.value(2, 2048), 0.0);
  EXPECT_NEAR(cal.value(2, 3071.5), 47.5, 1e-12);
  const auto p = cal.toArmPose(std::array<std::uint16_t, 3>{2100, 4095, 2048});
  EXPECT_DOUBLE_EQ(p.xMm, 160.0);
  EXPECT_DOUBLE_EQ(p.yMm, 300.0);
  EXPECT_DOUBLE_EQ(p.thetaDeg, 0.0);
}

TEST(ArmCalibration, BadTablesAreRefusedNamingTheChannel) {
  auto message = [](auto&& f) -> std::string {
    try {
      f();
    } catch (const pp5::InputError& e) {
      return e.what();
    }
    return "(no error)";
  };
  const std::string key = "board.arm.y_table";
  auto refused = [&](const std::vector<std::string>& rows, int channel, const std::string& part) {
    const std::string m = message([&] { parseArmTable(rows, channel, key); });
    EXPECT_NE(m.find(key), std::string::npos) << m;
    EXPECT_NE(m.find(std::string("arm's ") + kArmChannelNames[static_cast<std::size_t>(channel)] + " table"),
              std::string::npos)
        << m;
    EXPECT_NE(m.find(part), std::string::npos) << m;
  };
  refused({}, 1, "at least 2");
  refused({"0 1"}, 1, "at least 2");
  refused({"0 1", "10"}, 1, "row 2 \"10\" is not two numbers");
  refused({"0 1", "10 2 3"}, 2, "row 2");
  refused({"0 1", "ten 2"}, 0, "row 2");
  refused({"0 1", "10 2,"}, 1, "row 2");
  refused({"0 1", "10 2", "10 3"}, 1, "increase strictly");
  refused({"0 1", "10 2", "5 3"}, 2, "point 3 has count 5 after 10");
  refused({"0 1", "10 inf"}, 0, "not finite");

  pp5::sim::ArmSettings s;
  ArmCalibration cal = ArmCalibration::linear(pp5::sim::armAdc(s), s.referenceToTrackerMm, 0.0);
  cal.table[2] = {{5.0, 1.0}, {5.0, 2.0}};
  const std::string m = message([&] { cal.validate("board.arm"); });
  EXPECT_NE(m.find("board.arm: the arm's theta table"), std::string::npos) << m;
  cal = ArmCalibration::linear(pp5::sim::armAdc(s), s.referenceToTrackerMm, std::nan(""));
  EXPECT_NE(message([&] { cal.validate(); }).find("probe height"), std::string::npos);
}

}  // namespace
