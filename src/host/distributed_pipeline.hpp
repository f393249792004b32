#pragma once
// The distributed pipeline: the host rank's side of the GP and PP ranks
// (ranks/), behind the run loop's interface. It sends frames to the graphics
// processors under credit-based flow control (slab: pixels only to the GPs a
// frame can reach), broadcasts control changes with new epochs, assembles
// the pixel processors' tiles into the frame buffer, keeps the heartbeat, and
// with --verify runs the serial pipeline beside itself and requires every
// image to be bitwise equal. The host rank keeps only this messaging; the
// loop and the outputs are the same as in one process.
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "comm/messages.hpp"
#include "comm/transport.hpp"
#include "host/pipeline.hpp"
#include "host/run_loop.hpp"
#include "pipeline/partition.hpp"
#include "pipeline/rank_stats.hpp"
#include "pipeline/serial_pipeline.hpp"

namespace pp5::host {

class DistributedPipeline final : public Pipeline {
public:
  DistributedPipeline(comm::Transport& t, const RunJob& job);
  ~DistributedPipeline() override;

  std::vector<std::string> statsColumns() const override;
  void start() override;
  bool poll() override;
  std::chrono::milliseconds frameWait(bool) const override { return std::chrono::milliseconds(0); }
  void insert(AcquiredFrame& a) override;
  bool synchronous() const override { return j_.parallel.lockstep(); }
  bool steerable() const override { return shownEpoch_ == epoch_; }
  std::uint32_t control(std::uint32_t changes, const ViewState& next, bool lasting) override;
  void sync() override;
  ImageView image() const override;
  std::vector<float> composite(pp::CompositeMode mode) override;
  void verify(const std::vector<float>& got, const pp::CompositeMode* mode, const std::string& what) override;
  bool checksVolume() const override { return ref_ != nullptr; }
  bool requestVolume() override;
  void settle() override;
  const Volume& volume() override;
  PipelineCounters counters() const override;
  void streamEnded() override;
  std::string end(const RunEnd& e) override;

private:
  using Clock = std::chrono::steady_clock;
  comm::Transport& t_;
  const RunJob& j_;
  parallel::RankLayout L_;
  int w_, h_;
  std::uint32_t epoch_ = 0;
  std::vector<int> credits_;
  struct PpProgress {
    std::uint32_t epoch = 0;
    std::int64_t frame = -1;
  };
  std::vector<PpProgress> pp_;
  int requestsDone_ = 0;
  std::vector<float> fb_, requestFb_;
  std::int64_t imageFrame_ = -1;  // every frame up to this one is in fb_ (this epoch)
  // Until a new epoch's first whole image is in, fb_ goes on showing (and
  // updating) the epoch before (shownEpoch_, its progress shownPp_): the PPs
  // send the frames acquired before a control change in the old view first.
  // The new epoch's tiles gather in nextFb_ (every PP sends all its tiles
  // first in a new epoch) and replace fb_ at once.
  std::uint32_t shownEpoch_ = 0;
  std::vector<PpProgress> shownPp_;
  std::int64_t shownFrame_ = -1;
  std::vector<float> nextFb_;
  std::uint64_t sent_ = 0;    // frames sent
  PipelineCounters tally_;  // image updates assembled and busy times (counters() adds frames sent, layout, latency)
  std::uint64_t streamImages_ = 0;  // of them, while frames were streaming
  std::uint64_t verified_ = 0;
  FrameLatency latency_;
  // GP updates for frames (tick mode batches the frames waiting at a GP).
  std::uint64_t frameCredits_ = 0, framesBatched_ = 0;
  double gpUpdates_ = 0.0;
  std::uint32_t maxBatch_ = 0;
  parallel::StageClock clock_;
  parallel::StreamCpu streamCpu_;  // the stream of frames' CPU (cost model)

  std::unique_ptr<parallel::Partition> partition_;
  std::vector<std::int64_t> lastPixels_;  // per GP: the last frame whose pixels it got
  AcquiredFrame prev_;
  bool hasPrev_ = false;
  std::uint64_t pixelMessages_ = 0, poseOnlyMessages_ = 0, previousMessages_ = 0;

  std::unique_ptr<serial::SerialPipeline> ref_;
  bool volumeOutstanding_ = false;  // a snapshot asked for is on its way
  Clock::time_point lastKeepAlive_ = Clock::now();
  std::vector<Clock::time_point> lastHeard_;  // per rank: the last message from it (the heartbeat)
  Volume volume_;
  int volumesDone_ = 0;
  VolumeChange volumeChange_;  // the boxes the pieces of the snapshot under way came in
  std::vector<comm::ReportMsg> reports_;
  // Sample bytes the GPs sent for frames' incremental updates and for full
  // re-samples after control changes (their credits' counts).
  std::uint64_t incrementalSampleBytes_ = 0, fullSampleBytes_ = 0;
  // Tile bytes the PPs sent for incremental image updates (not full images
  // after a control change, not answers to requests).
  std::uint64_t incrementalTileBytes_ = 0;

  void handle(const comm::Message& m);
  void onTile(const comm::Message& m);
  void onVolume(const comm::Message& m);
  void imageHas(std::int64_t from, std::int64_t f);
  void advanceShown();
  void advanceImage();
  void emitImage();
  void row(const comm::Header& h, int rank, parallel::Role role, const comm::StageTimes& st, std::uint64_t samples,
           std::uint64_t bytes, std::uint64_t dirty, double latency, bool control);
  // Handles messages until `done()`, waiting for them; CommError names `what`
  // when nothing arrives for parallel.timeout_s.
  template <typename F>
  void waitUntil(F done, const std::string& what);
  std::string rankName(int r) const;
  std::pair<int, double> quietestRank() const;
  void heartbeat();
  void waitCredits();
  void waitImage(std::int64_t frame);
  void askVolume();
  // The closing report: printed, and returned as summary.json's text.
  std::string summary(const RunEnd& e);
};

template <typename F>
inline void DistributedPipeline::waitUntil(F done, const std::string& what) {
  while (!done()) {
    const double w0 = t_.waitSeconds();
    comm::Message m;
    try {
      m = t_.wait(what);
    } catch (const comm::CommError& e) {
      // Name the rank that went quiet, as the heartbeat would.
      const auto [r, age] = quietestRank();
      throw comm::CommError(fmt::format("{}; {} was heard from last, {:.1f} s ago", e.what(), rankName(r), age));
    }
    clock_.add(comm::kWait, 1e3 * (t_.waitSeconds() - w0));
    handle(m);
  }
}

}  // namespace pp5::host
