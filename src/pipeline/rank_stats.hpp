#pragma once
// Per-stage timers and the end-of-run report every non-host rank sends.
#include <chrono>
#include <ctime>

#include "comm/messages.hpp"
#include "pipeline/schedule.hpp"
#include "comm/transport.hpp"

namespace pp5::parallel {

inline double processCpuSeconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

// The CPU a rank spends on the stream of frames, and the bytes it moves
// meanwhile, for the bench's cost model: from the start of its work on the
// first frame to the end of its work on the last, so that start-up and the
// final pass are left out. begin() marks the start once; every end() moves
// the end.
class StreamCpu {
public:
  void begin(const comm::Transport& t) {
    if (start_ >= 0.0) return;
    start_ = processCpuSeconds();
    bytes0_ = moved(t);
  }
  void end(const comm::Transport& t) {
    if (start_ < 0.0) return;
    end_ = processCpuSeconds();
    bytes1_ = moved(t);
  }
  double seconds() const { return end_ > start_ ? end_ - start_ : 0.0; }
  std::uint64_t bytes() const { return bytes1_ > bytes0_ ? bytes1_ - bytes0_ : 0; }

private:
  static std::uint64_t moved(const comm::Transport& t) {
    const comm::PeerCounters c = t.totals();
    return c.bytesSent + c.bytesReceived;
  }
  double start_ = -1.0, end_ = -1.0;
  std::uint64_t bytes0_ = 0, bytes1_ = 0;
};

// Times stages of one update, and adds them to the run's totals.
class StageClock {
public:
  using Clock = std::chrono::steady_clock;
  // Starts timing `stage` (ending the stage before, if any).
  void start(comm::Stage s) {
    stop();
    stage_ = s;
    t0_ = Clock::now();
  }
  void stop() {
    if (stage_ < 0) return;
    const float ms = std::chrono::duration<float, std::milli>(Clock::now() - t0_).count();
    current_.ms[stage_] += ms;
    total_.ms[stage_] += ms;
    stage_ = -1;
  }
  void add(comm::Stage s, double ms) {
    current_.ms[s] += static_cast<float>(ms);
    total_.ms[s] += static_cast<float>(ms);
  }
  // The times since the last take(), which starts a new update.
  comm::StageTimes take() {
    stop();
    const comm::StageTimes t = current_;
    current_ = {};
    return t;
  }
  const comm::StageTimes& total() const { return total_; }

private:
  int stage_ = -1;
  Clock::time_point t0_;
  comm::StageTimes current_, total_;
};

inline comm::ReportMsg makeReport(const comm::Transport& t, Role role, const comm::StageTimes& total, double wallS,
                                  std::uint64_t dropped, std::uint64_t memoryBytes, const StreamCpu& stream) {
  comm::ReportMsg r;
  r.h.tag = comm::kTagReport;
  r.rank = static_cast<std::uint32_t>(t.rank());
  r.role = static_cast<std::uint32_t>(role);
  r.total = total;
  r.cpuS = processCpuSeconds();
  r.streamCpuS = stream.seconds();
  r.streamBytes = stream.bytes();
  r.wallS = wallS;
  const comm::PeerCounters c = t.totals();
  r.bytesSent = c.bytesSent;
  r.bytesReceived = c.bytesReceived;
  r.messagesSent = c.messagesSent;
  r.messagesReceived = c.messagesReceived;
  r.dropped = dropped;
  r.memoryBytes = memoryBytes;
  for (int k = 0; k < comm::kTrafficKinds; ++k) r.bytesByKind[k] = t.bytesSentByKind()[static_cast<std::size_t>(k)];
  return r;
}

// A rank's life: built from its configuration, ready once every rank is
// (the host starts acquiring then), then its loop until the end of the run.
template <class Rank, class Config>
void runRank(comm::Transport& t, const Config& c) {
  Rank rank(t, c);
  t.barrier();
  rank.run();
}

}  // namespace pp5::parallel
