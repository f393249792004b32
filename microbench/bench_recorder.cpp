// What recording a frame costs the thread that records it, on the doll's
// frames (256 x 405 bytes of B-mode):
//  - BM_RecordOnTheCallersThread: host::Recorder (journal, zlib, the
//    journal's periodic sync) on the caller's thread, as the viewer's page
//    recording was written on the host's loop before the tenth session;
//  - BM_RecordQueued: host::RecorderThread, which the host's loop now calls:
//    a copy into the queue, the writing on the recorder's own thread (each
//    iteration's time is the caller's alone; the writes go on beside it).
// Run: build/microbench/pp5_bench --benchmark_filter=Record --benchmark_repetitions=3 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <unistd.h>

#include <filesystem>
#include <string>
#include <vector>

#include "host/recorder.hpp"
#include "sim/simulate.hpp"

namespace {

using namespace pp5;

const std::vector<Frame>& frames() {
  static const std::vector<Frame> f = [] {
    sim::SimSettings ss;  // the doll, the paper's probe: the main job's frames
    const sim::SweepSimulator sim(ss);
    std::vector<Frame> out;
    sim.run(0, [&](Frame&& fr) {
      if (out.size() < 16) out.push_back(std::move(fr));
    });
    return out;
  }();
  return f;
}

std::string scratch(const char* name) {
  const auto dir = std::filesystem::temp_directory_path() / (std::string("pp5bench-") + name + "-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return (dir / "rec.mha").string();
}

template <class R>
void record(benchmark::State& state, R& rec) {
  const auto& f = frames();
  std::size_t i = 0;
  for (auto _ : state) {
    rec.writePlaced(f[i % f.size()], Mat4(1.0), 0.033 * static_cast<double>(i));
    ++i;
  }
  state.counters["frame_kB"] = static_cast<double>(f.front().pixels.size()) / 1e3;
}

void BM_RecordOnTheCallersThread(benchmark::State& state) {
  const std::string path = scratch("direct");
  {
    host::Recorder rec(path);
    record(state, rec);
  }
  std::filesystem::remove_all(std::filesystem::path(path).parent_path());
}
BENCHMARK(BM_RecordOnTheCallersThread)->Unit(benchmark::kMillisecond)->Iterations(60);

void BM_RecordQueued(benchmark::State& state) {
  const std::string path = scratch("queued");
  {
    host::RecorderThread rec;
    rec.record(path);
    record(state, rec);
    rec.finish();  // after the timed loop: the writes themselves are not the caller's
  }
  std::filesystem::remove_all(std::filesystem::path(path).parent_path());
}
BENCHMARK(BM_RecordQueued)->Unit(benchmark::kMillisecond)->Iterations(60);

}  // namespace
