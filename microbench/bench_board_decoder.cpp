// The interface board's frame decoder (interface_board/wire.hpp) on one core:
// a stream of 640x480 u8 frames with arm poses, as the board sends them,
// fed in USB bulk-sized chunks. Bytes = stream bytes decoded (MB/s).
//  - Decoder/16384: 16 KiB transfers (the driver's default).
//  - Decoder/512: 512-byte transfers (one full-speed bulk packet each).
//  - DecoderResync/16384: every 8th frame cut short after half its payload,
//    so each costs a payload CRC failure and a rescan.
// Run: build/microbench/pp5_bench --benchmark_filter=Decoder
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

#include "interface_board/wire.hpp"

namespace {

using pp5::board::FrameDecoder;
using pp5::board::WireFrame;

std::vector<std::uint8_t> makeStream(int frames, bool cutSome) {
  std::mt19937 rng(1);
  std::vector<std::uint8_t> s;
  WireFrame f;
  f.width = 640;
  f.height = 480;
  f.bytesPerPixel = 1;
  f.poseKind = pp5::board::PoseKind::ArmCounts;
  f.pixels.resize(640 * 480);
  for (int k = 0; k < frames; ++k) {
    for (auto& p : f.pixels) p = static_cast<std::uint8_t>(rng() >> 24);  // speckle-like noise
    f.sequence = static_cast<std::uint32_t>(k);
    f.timestampUs = static_cast<std::uint64_t>(k) * 33333;
    f.armCounts = {static_cast<std::uint16_t>(k % 4096), 2000, 2048};
    const std::size_t before = s.size();
    pp5::board::encodeFrame(f, s);
    if (cutSome && k % 8 == 3) s.resize(before + pp5::board::kHeaderBytes + f.pixels.size() / 2);
  }
  return s;
}

void run(benchmark::State& state, bool cutSome) {
  const auto chunk = static_cast<std::size_t>(state.range(0));
  const std::vector<std::uint8_t> stream = makeStream(32, cutSome);
  std::uint64_t frames = 0, pixelSum = 0;
  for (auto _ : state) {
    FrameDecoder d;
    for (std::size_t i = 0; i < stream.size(); i += chunk)
      d.feed(std::span(stream.data() + i, std::min(chunk, stream.size() - i)), [&](WireFrame&& f) {
        ++frames;
        pixelSum += f.pixels[f.pixels.size() / 2];
      });
    benchmark::DoNotOptimize(pixelSum);
  }
  state.SetBytesProcessed(static_cast<std::int64_t>(state.iterations() * stream.size()));
  state.counters["frames/s"] = benchmark::Counter(static_cast<double>(frames), benchmark::Counter::kIsRate);
}

void BM_Decoder(benchmark::State& state) { run(state, false); }
void BM_DecoderResync(benchmark::State& state) { run(state, true); }

}  // namespace

BENCHMARK(BM_Decoder)->Arg(16384)->Arg(512)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_DecoderResync)->Arg(16384)->Unit(benchmark::kMillisecond);
