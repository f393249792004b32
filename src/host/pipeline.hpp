#pragma once
// The pipeline the one run loop (host/run_loop.hpp) drives: reconstruct,
// shade, sample and composite each frame, and re-render on a control change.
// Two implementations share this interface, as OSPRay's local and
// distributed devices share one API: host/local_pipeline.hpp runs every stage
// in this process; host/distributed_pipeline.hpp is the host rank's side of
// the GP and PP ranks, over the transport. The loop never asks which one it
// drives.
#include <chrono>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "comm/messages.hpp"
#include "core/grid.hpp"
#include "formats/volume_io.hpp"
#include "host/acquisition.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/ray_cache.hpp"

namespace pp5::host {

// What the user steers while the run goes on (core/view_state.hpp); a control
// message carries it as it is.
using ViewState = pp5::ViewState;

// An image the pipeline made: RGBA floats (premultiplied), holding every
// frame up to `frame` in `epoch`'s view. `latest`: of the newest epoch (an
// older view's image can still come while a new one is being made).
struct ImageView {
  const std::vector<float>* rgba = nullptr;
  int width = 0, height = 0;
  std::uint32_t epoch = 0;
  std::int64_t frame = -1;
  bool latest = true;
};

// Where a volume snapshot may differ from the one before it: the voxel
// boxes its pieces came in, or everything (the first, or a pipeline that does
// not track them). Outside them the voxels are as they were.
struct VolumeChange {
  bool all = true;
  std::vector<gp::Box3> boxes;

  // This and then `c`; everything past kMostBoxes (a sink that seldom asks).
  void add(const VolumeChange& c) {
    constexpr std::size_t kMostBoxes = std::size_t{1} << 14;
    if (all) return;
    if (c.all || boxes.size() + c.boxes.size() > kMostBoxes) {
      *this = VolumeChange{};
      return;
    }
    boxes.insert(boxes.end(), c.boxes.begin(), c.boxes.end());
  }
};

// What the pipeline tells the loop as it works; the loop passes it on to the sinks.
struct PipelineEvents {
  // Frame k went in (after it was sent, before its image is in).
  std::function<void(const AcquiredFrame&, std::uint64_t k)> frame;
  std::function<void(const ImageView&)> image;
  // A volume asked for with requestVolume(), and where it may differ from the
  // snapshot before it.
  std::function<void(const Volume&, const VolumeChange&)> volume;
  // A row of the statistics file (columns: statsColumns()).
  std::function<void(const std::vector<double>&)> stats;
};

// The counters behind the viewer's figures.
struct PipelineCounters {
  std::uint64_t frames = 0, images = 0;
  double gpBusyMs = 0, ppBusyMs = 0;  // summed over the processors of each kind
  int gps = 1, pps = 1;
  double latencyMedianMs = 0, latencyP95Ms = 0;  // over the last frames' latencies
};

// q-quantile of `v` (the value at rank ceil(q n)); 0 for none.
double percentile(std::vector<double> v, double q);

// Each frame's latency: from its arrival to the first image that holds it.
class FrameLatency {
public:
  using Clock = std::chrono::steady_clock;
  void arrived(Clock::time_point t) {
    arrival_.push_back(t);
    ms_.push_back(-1.0);
  }
  // Frames `from` to `to` are in the image shown now: `f(i, ms)` for each
  // whose latency this sets.
  template <typename F>
  void imageHas(std::int64_t from, std::int64_t to, F f) {
    const auto now = Clock::now();
    for (std::int64_t i = from < 0 ? 0 : from; i <= to && i < static_cast<std::int64_t>(ms_.size()); ++i) {
      double& ms = ms_[static_cast<std::size_t>(i)];
      if (ms >= 0.0) continue;
      ms = std::chrono::duration<double, std::milli>(now - arrival_[static_cast<std::size_t>(i)]).count();
      f(i, ms);
    }
  }
  // The latencies set, of the last `n` of them at most (0: all), newest first.
  std::vector<double> measured(std::size_t n = 0) const;
  // The median and 95th percentile of the last 90 set, into the counters.
  void recent(PipelineCounters& c) const;

private:
  std::vector<Clock::time_point> arrival_;
  std::vector<double> ms_;
};

// What the run loop knows at the end, for the pipeline's closing report.
struct RunEnd {
  double streamS = 0, totalS = 0;        // streaming frames; the whole run
  std::uint64_t dropped = 0, skipped = 0;  // acquisition's drops; frames the capture left out
  double captureIntervalMm = 0;
  std::string sourceStatsJson;           // a live source's counters ("" = none)
  std::vector<double> orbitMs;           // each orbit view's full re-render
};

class Pipeline {
public:
  virtual ~Pipeline() = default;
  void setEvents(PipelineEvents e) { events_ = std::move(e); }

  // The statistics file's columns.
  virtual std::vector<std::string> statsColumns() const = 0;
  // Every part is ready for the first frame (the distributed one: a barrier).
  virtual void start() {}
  // Handles what has arrived (messages, the heartbeat); whether anything did.
  virtual bool poll() { return false; }
  // How long the loop may wait on the acquisition queue for the next frame
  // (zero: not at all; the loop polls and backs off instead).
  virtual std::chrono::milliseconds frameWait(bool steered) const = 0;

  // The next frame in (it may be moved from). A synchronous pipeline has its
  // image once sync() returns; the distributed one in tick mode later.
  virtual void insert(AcquiredFrame& a) = 0;
  virtual bool synchronous() const = 0;
  // Whether a change the user asked for can go in now (the distributed one
  // takes the next once the last one's first whole image is in).
  virtual bool steerable() const { return true; }
  // A control change: the pipeline renders `next` from now on, as a new
  // epoch, which it returns. ControlMsg::kFinish: the reconstruction's final
  // passes. `lasting` = false: a change of the run's own that it undoes.
  virtual std::uint32_t control(std::uint32_t changes, const ViewState& next, bool lasting) = 0;
  // Waits until every frame in and the last change are in image().
  virtual void sync() = 0;
  // The image shown now.
  virtual ImageView image() const = 0;
  // The current samples composited in full in `mode` (one of the live mode's
  // kind: colour or grey values).
  virtual std::vector<float> composite(pp::CompositeMode mode) = 0;
  // Beside a reference run (--verify): `got` must equal the reference's
  // image (in `mode`, or the live one), else InvariantError naming `what`.
  virtual void verify(const std::vector<float>& got, const pp::CompositeMode* mode, const std::string& what) {
    (void)got, (void)mode, (void)what;
  }
  // Whether the final volume is wanted whatever the outputs (a reference to compare it with).
  virtual bool checksVolume() const { return false; }

  // Asks for a snapshot of the reconstruction, handed to events.volume when
  // it is in; false while one is on its way already.
  virtual bool requestVolume() = 0;
  // Waits until no snapshot is on its way.
  virtual void settle() {}
  // The reconstruction now (waits for it).
  virtual const Volume& volume() = 0;

  virtual PipelineCounters counters() const = 0;
  // The input ended (every frame in): what a pipeline does once, before the final passes.
  virtual void streamEnded() {}
  // The run is over: every part reports and stops. Prints the pipeline's
  // closing lines; returns the run summary as JSON ("" = none).
  virtual std::string end(const RunEnd& e) = 0;

protected:
  PipelineEvents events_;
};

}  // namespace pp5::host
