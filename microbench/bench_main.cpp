// Google Benchmark suite. Speed targets live here, never in unit tests.
// Run: build/microbench/pp5_bench [--benchmark_filter=...]
#include <benchmark/benchmark.h>

#include <string>

#include "core/config.hpp"
#include "core/frame.hpp"
#include "formats/sequence_io.hpp"
#include "sim/simulate.hpp"

namespace {

const std::string kData = PP5_DATA_DIR;

// Streaming read of a zlib-compressed PLUS sequence (820x616 u8 frames).
void BM_ReadCompressedSequence(benchmark::State& state) {
  const std::string path = kData + "/SpinePhantomFreehand.igs.mha";
  std::int64_t frames = 0, bytes = 0;
  for (auto _ : state) {
    auto reader = pp5::SequenceReader::open(path);
    pp5::Frame f;
    while (reader->next(f)) {
      ++frames;
      bytes += static_cast<std::int64_t>(f.byteSize());
    }
  }
  state.SetItemsProcessed(frames);
  state.SetBytesProcessed(bytes);
}
BENCHMARK(BM_ReadCompressedSequence)->Unit(benchmark::kMillisecond);

// One B-mode frame of the default doll sweep (paper35 probe, 256x405), on the
// calling thread. Frames from the middle of the sweep cross the doll's body.
void BM_SimulateDollFrame(benchmark::State& state) {
  pp5::sim::SimSettings s;
  pp5::ConfigSchema schema;
  pp5::sim::registerOptions(schema, s);
  const pp5::sim::SweepSimulator sim(s);
  std::size_t i = sim.frameCount() / 4;
  for (auto _ : state) {
    benchmark::DoNotOptimize(sim.frame(i));
    i = i + 1 < 3 * sim.frameCount() / 4 ? i + 1 : sim.frameCount() / 4;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_SimulateDollFrame)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
