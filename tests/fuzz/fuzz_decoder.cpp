// libFuzzer target for the interface board's frame decoder (scripts/fuzz.sh
// builds and runs it). tests/test_board_wire.cpp includes this file to replay
// the corpus through the same checks in the normal build.
//
// Input: byte 0 = c; the next (c & 7) bytes are feed sizes, each (b + 1),
// times 64 when c & 8; the rest is the byte stream, fed in chunks of those
// sizes in turn (the whole rest at once when there are none).
//
// Checks, with small limits (1 MiB payload, 1024x1024):
//  - memory: buffered() <= header + max payload after every feed;
//  - every byte accounted for: bytesIn == frameBytes + skippedBytes + buffered();
//  - frames well formed: pixels.size() == w * h * bpp, valid kind and counts;
//  - the split does not matter: one feed gives the same frames and counters;
//  - re-encoding the frames decodes back to the same frames, without errors.
// A failed check throws; libFuzzer reports the uncaught exception as a crash.
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include "interface_board/wire.hpp"

namespace pp5::fuzz {

using board::DecoderCounters;
using board::FrameDecoder;
using board::WireFrame;

inline void require(bool ok, const std::string& what) {
  if (!ok) throw std::logic_error("fuzz_decoder: " + what);
}

inline board::DecoderLimits fuzzLimits() {
  board::DecoderLimits l;
  l.maxPayloadBytes = 1u << 20;
  l.maxWidth = 1024;
  l.maxHeight = 1024;
  return l;
}

inline bool sameFrame(const WireFrame& a, const WireFrame& b) {
  // Bitwise on the matrix: a NaN must survive the round trip too.
  return a.sequence == b.sequence && a.timestampUs == b.timestampUs && a.width == b.width && a.height == b.height &&
         a.bytesPerPixel == b.bytesPerPixel && a.poseKind == b.poseKind && a.flags == b.flags &&
         a.armCounts == b.armCounts && std::memcmp(a.matrix.data(), b.matrix.data(), sizeof(a.matrix)) == 0 &&
         a.pixels == b.pixels;
}

inline bool sameCounters(const DecoderCounters& a, const DecoderCounters& b) {
  return a.bytesIn == b.bytesIn && a.frames == b.frames && a.headerCrcErrors == b.headerCrcErrors &&
         a.payloadCrcErrors == b.payloadCrcErrors && a.badHeaders == b.badHeaders && a.resyncs == b.resyncs &&
         a.skippedBytes == b.skippedBytes && a.sequenceGaps == b.sequenceGaps && a.frameBytes == b.frameBytes;
}

inline void checkAccounting(const FrameDecoder& d, const board::DecoderLimits& l) {
  const DecoderCounters& c = d.counters();
  require(d.buffered() <= board::kHeaderBytes + l.maxPayloadBytes, "buffered() over header + max payload");
  require(c.bytesIn == c.frameBytes + c.skippedBytes + d.buffered(), "bytesIn != frameBytes + skipped + buffered");
}

inline void checkFrame(const WireFrame& f, const board::DecoderLimits& l) {
  require(f.bytesPerPixel == 1 || f.bytesPerPixel == 2, "bytes per pixel not 1 or 2");
  require(f.width >= 1 && f.width <= l.maxWidth && f.height >= 1 && f.height <= l.maxHeight, "size out of limits");
  require(f.pixels.size() == std::size_t{f.width} * f.height * f.bytesPerPixel, "pixels.size() != w * h * bpp");
  require(static_cast<int>(f.poseKind) <= 2, "pose kind out of range");
  for (auto c : f.armCounts) require(c <= 4095, "arm count over 4095");
}

// Runs every check on one input; throws std::logic_error on a failure.
inline void checkDecoderInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return;
  const std::size_t nSizes = std::min<std::size_t>(data[0] & 7u, size - 1);
  const std::size_t scale = (data[0] & 8u) ? 64 : 1;
  std::vector<std::size_t> sizes;
  for (std::size_t i = 0; i < nSizes; ++i) sizes.push_back((data[1 + i] + 1u) * scale);
  const std::uint8_t* stream = data + 1 + nSizes;
  const std::size_t n = size - 1 - nSizes;

  const board::DecoderLimits lim = fuzzLimits();
  FrameDecoder split(lim);
  std::vector<WireFrame> frames;
  std::size_t pos = 0, k = 0;
  while (pos < n) {
    const std::size_t take = sizes.empty() ? n : std::min(sizes[k++ % sizes.size()], n - pos);
    split.feed({stream + pos, take}, [&](WireFrame&& f) { frames.push_back(std::move(f)); });
    pos += take;
    checkAccounting(split, lim);
  }
  require(split.counters().frames == frames.size(), "frames counter != frames handed out");
  for (const WireFrame& f : frames) checkFrame(f, lim);

  FrameDecoder whole(lim);
  std::vector<WireFrame> frames1;
  whole.feed({stream, n}, [&](WireFrame&& f) { frames1.push_back(std::move(f)); });
  require(frames1.size() == frames.size(), "the split changed the number of frames");
  for (std::size_t i = 0; i < frames.size(); ++i) require(sameFrame(frames[i], frames1[i]), "the split changed a frame");
  require(sameCounters(split.counters(), whole.counters()), "the split changed the counters");
  require(split.buffered() == whole.buffered(), "the split changed buffered()");

  std::vector<std::uint8_t> again;
  for (const WireFrame& f : frames) board::encodeFrame(f, again);
  FrameDecoder redo(lim);
  std::vector<WireFrame> frames2;
  redo.feed(again, [&](WireFrame&& f) { frames2.push_back(std::move(f)); });
  require(frames2.size() == frames.size(), "re-encoded frames did not all decode");
  for (std::size_t i = 0; i < frames.size(); ++i) require(sameFrame(frames[i], frames2[i]), "re-encoded frame differs");
  const DecoderCounters& c = redo.counters();
  require(c.headerCrcErrors + c.payloadCrcErrors + c.badHeaders + c.resyncs + c.skippedBytes == 0,
          "re-encoded stream gave errors");
  require(redo.buffered() == 0, "re-encoded stream left bytes buffered");
}

}  // namespace pp5::fuzz

#ifdef PP5_FUZZ_MAKE_CORPUS
// The seed corpus: `fuzz_decoder_seeds DIR` writes seed-NN files (see
// scripts/fuzz.sh --seeds). Each is a control byte and feed sizes as above,
// then a stream: good frames, frames cut short or corrupted, impossible
// headers with good CRCs (a 4 GB claim among them), garbage and partial magics.
#include <cmath>
#include <fstream>
#include <limits>

namespace {

using pp5::board::PoseKind;
using pp5::board::WireFrame;
using Bytes = std::vector<std::uint8_t>;

WireFrame frame(std::uint32_t seq, std::uint16_t w, std::uint16_t h, std::uint8_t bpp, PoseKind kind) {
  WireFrame f;
  f.sequence = seq;
  f.timestampUs = 1000u * seq + 7;
  f.width = w;
  f.height = h;
  f.bytesPerPixel = bpp;
  f.poseKind = kind;
  f.armCounts = {static_cast<std::uint16_t>(seq * 13 % 4096), 2048, 4095};
  for (std::size_t i = 0; i < 12; ++i) f.matrix[i] = (i % 5 == 0) ? 1.0 : 0.25 * static_cast<double>(i);
  f.pixels.resize(std::size_t{w} * h * bpp);
  for (std::size_t i = 0; i < f.pixels.size(); ++i) f.pixels[i] = static_cast<std::uint8_t>(i * 31 + seq);
  return f;
}
Bytes enc(const WireFrame& f) {
  Bytes b;
  pp5::board::encodeFrame(f, b);
  return b;
}
// Overwrites header bytes and recomputes the header CRC, so that only the
// fields are wrong.
Bytes patched(Bytes b, std::size_t off, std::initializer_list<std::uint8_t> v) {
  std::copy(v.begin(), v.end(), b.begin() + static_cast<std::ptrdiff_t>(off));
  const std::uint32_t c = pp5::board::crc32(std::span(b.data(), 156));
  for (int i = 0; i < 4; ++i) b[156 + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(c >> (8 * i));
  return b;
}
Bytes cat(std::initializer_list<Bytes> parts) {
  Bytes out;
  for (const Bytes& p : parts) out.insert(out.end(), p.begin(), p.end());
  return out;
}
Bytes cut(Bytes b, std::size_t n) {
  b.resize(n);
  return b;
}
Bytes flip(Bytes b, std::size_t i) {
  b[i] ^= 0x10;
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) return 2;
  const std::string dir = argv[1];
  const Bytes a = enc(frame(1, 8, 6, 1, PoseKind::None)), b = enc(frame(2, 5, 4, 2, PoseKind::ArmCounts)),
              c = enc(frame(3, 7, 3, 1, PoseKind::Matrix)), d = enc(frame(4, 16, 16, 1, PoseKind::ArmCounts));
  WireFrame nanFrame = frame(9, 3, 3, 2, PoseKind::Matrix);
  nanFrame.matrix[4] = std::numeric_limits<double>::quiet_NaN();
  nanFrame.flags = pp5::board::kFlagImageInvalid | pp5::board::kFlagPoseInvalid;
  const Bytes garbage = {0x00, 0x50, 0x48, 0x35, 0x00, 0x50, 0x50, 0x48, 0xFF, 0x46, 0x35, 0x50};
  const Bytes magic = {0x50, 0x48, 0x35, 0x46};
  // Control prefixes: whole, 1-byte feeds, sizes 3/7/50, x64 sizes 1/2.
  const Bytes whole = {0}, bytewise = {1, 0}, mixed = {3, 2, 6, 49}, big = {8 + 2, 0, 1};
  std::vector<Bytes> seeds = {
      cat({whole, a}),
      cat({bytewise, a, b}),
      cat({mixed, a, b, c}),
      cat({big, a, b, c, d}),
      cat({mixed, a, cut(b, 160 + 9), c}),               // payload cut short
      cat({bytewise, a, cut(b, 80), c}),                  // header cut short
      cat({mixed, flip(a, 20), b}),                       // header corrupted
      cat({whole, a, flip(b, 170), c}),                   // payload corrupted
      cat({mixed, patched(a, 24, {0xFF, 0xFF, 0xFF, 0xFF, 1, 0, 0, 0, 0x01, 0x00, 0xFE, 0xFF}), b}),  // 4 GB
      cat({whole, patched(a, 24, {0x01, 0x04, 6, 0, 1, 0, 0, 0, 0x06, 0x18, 0, 0}), b}),  // width 1025
      cat({whole, patched(a, 4, {2, 0}), b}),             // version 2
      cat({whole, patched(a, 6, {161, 0}), b}),           // header size
      cat({whole, patched(a, 28, {3}), b}),               // 3 bytes per pixel
      cat({whole, patched(a, 32, {49, 0, 0, 0}), b}),     // payload length off by one
      cat({whole, patched(b, 38, {0x00, 0x10}), c}),      // arm count 4096
      cat({whole, patched(a, 29, {3}), b}),               // pose kind 3
      cat({mixed, garbage, a, garbage, b, magic, c}),
      cat({bytewise, magic, magic, a}),
      cat({whole, enc(frame(0xFFFFFFFFu, 2, 2, 1, PoseKind::None)), enc(frame(0, 2, 2, 1, PoseKind::None)),
           enc(frame(5, 2, 2, 1, PoseKind::None))}),      // wrap, then a gap
      cat({whole, enc(frame(1, 1, 1, 1, PoseKind::None)), enc(frame(2, 1, 1, 2, PoseKind::None)),
           enc(frame(3, 1, 1, 1, PoseKind::ArmCounts))}),
      cat({mixed, enc(nanFrame)}),
      cat({mixed, a, cut(d, 200), cut(c, 100), b, c}),    // two cuts in a row
      cat({whole, cut(a, 3)}),                            // a partial magic at the end
      cat({big, d, d, d}),                                // repeated sequence numbers
      cat({mixed, b, Bytes(300, 0x50), c}),
      cat({whole, flip(a, 157), flip(b, 0), c}),          // header CRC byte, then a broken magic
  };
  for (std::size_t i = 0; i < seeds.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "/seed-%02zu", i);
    std::ofstream out(dir + name, std::ios::binary);
    out.write(reinterpret_cast<const char*>(seeds[i].data()), static_cast<std::streamsize>(seeds[i].size()));
    if (!out) return 1;
  }
  return 0;
}
#elif !defined(PP5_FUZZ_NO_ENTRY)
extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  pp5::fuzz::checkDecoderInput(data, size);
  return 0;
}
#endif
