#pragma once
// Sources, frame preprocessing and the acquisition thread of the host rank.
//
// A source hands tracked frames to a sink in order. The host runs it in its
// own thread, so that a live source is never blocked by MPI: frames go into
// a bounded queue. A file source (or the simulator) waits when the queue is
// full, so it runs as fast as the pipeline allows; a live source never waits:
// when the queue is full it drops a frame by the stated policy and counts it.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <optional>
#include <mutex>
#include <string>
#include <thread>

#include <glm/glm.hpp>

#include "core/frame.hpp"
#include "core/grid.hpp"
#include "core/transform.hpp"
#include "host/capture.hpp"
#include "core/enum_names.hpp"

namespace pp5::host {

using FrameSink = std::function<void(const Frame&, const Mat4&, double)>;

struct Source {
  std::string description;
  std::uint64_t frames = 0;  // expected, for progress (0 = unknown)
  Grid grid;                 // the reconstruction grid for this source
  bool live = false;         // drops when behind rather than waiting
  std::function<void(const FrameSink&)> run;
  // Live sources: makes run() return soon (Ctrl-C), even while no frame comes.
  std::function<void()> interrupt;
  // Live sources: the device's counters as a JSON object, for summary.json.
  std::function<std::string()> statsJson;
  // The frames' ImageToProbe (pixels -> probe, mm), where the source knows
  // it (the simulated probe, a device set's calibration): the probe's pose is
  // then ImageToReference times its inverse (ProbeToReference, for clients).
  std::optional<Mat4> imageToProbe;
  // Work before the first frame that may take seconds (the simulated sweep's
  // cache fill), or empty. The host runs it once the viewer's URL is out,
  // before the first frame (the other ranks wait at the start barrier); a
  // source whose prepare was not run runs it itself.
  std::function<void()> prepare;
};

// Crop (x, y, width, height in pixels, as run.crop_origin and run.crop_size;
// width 0 = none), then subsample by an
// integer factor (the mean of each factor x factor block). The pose follows:
// new pixel (i, j) sits where the old block's centre was.
struct Preprocess {
  glm::ivec4 crop{0, 0, 0, 0};
  int subsample = 1;
  bool identity() const { return crop.z == 0 && subsample == 1; }
};
// InputError naming the frame when the crop does not fit inside it.
void preprocess(const Preprocess& p, Frame& f, Mat4& imageToReference);
// What preprocess() multiplies a frame's pose by on the right: a new pixel's
// indices -> the old pixel indices where its block's centre was.
Mat4 preprocessPixels(const Preprocess& p);

enum class DropPolicy { Oldest, Newest };
DropPolicy dropPolicyFromName(const std::string& name);  // "oldest" | "newest"

struct AcquiredFrame {
  Frame frame;
  Mat4 imageToReference{1.0};
  double timeS = 0.0;
  std::chrono::steady_clock::time_point arrival;
};

// Runs a source in its own thread into a bounded queue.
class Acquisition {
public:
  // paceFps > 0: deliver frames at that rate, as a live scanner would (the
  // source then counts as live). captureIntervalMm > 0: only the frames the
  // probe moved that far for (IntervalCapture, after preprocessing); a frame
  // left out still takes its place in the paced timeline.
  Acquisition(Source source, Preprocess pre, std::size_t capacity, DropPolicy policy, double paceFps,
              double captureIntervalMm = 0.0);
  ~Acquisition();  // stops and joins the thread

  // The next frame if one is queued.
  bool tryPop(AcquiredFrame& out);
  // The next frame, waiting at most `timeout` for one (false: none came, or the source ended).
  bool popFor(AcquiredFrame& out, std::chrono::milliseconds timeout);
  // True once the source has ended and the queue is empty. Rethrows the
  // source's error, if it had one.
  bool finished();
  // Asks the source to stop (Ctrl-C); frames already queued are still served.
  void stop();
  // One step of a loop whose viewer has paused acquisition: a live (or
  // paced) source's next frame goes by unused and is counted; a file's wait
  // (a short sleep). False once the source has ended and nothing is queued.
  bool whilePaused();

  // The progress line a run logs: how far the source is (frames dropped or
  // left out count) and how fast `through` frames went into the pipeline in
  // `seconds`.
  void logProgress(std::uint64_t through, double seconds) const;
  // The run's closing lines on what did not reach the pipeline: drops,
  // frames passed by while paused, frames the capture left out (each only
  // when there were any).
  void printCounts() const;

  // Frames the source has given so far: queued, dropped or left out by the capture.
  std::uint64_t given() const { return given_; }
  std::uint64_t delivered() const { return delivered_; }
  std::uint64_t dropped() const { return dropped_; }
  // Frames that went by while the viewer paused acquisition.
  std::uint64_t passedWhilePaused() const { return passedWhilePaused_; }
  // Frames constant-interval capture left out.
  std::uint64_t skipped() const { return skipped_; }

private:
  Source source_;
  Preprocess pre_;
  std::size_t capacity_;
  DropPolicy policy_;
  double paceFps_;
  bool live_;
  std::mutex m_;
  std::condition_variable cv_;
  std::deque<AcquiredFrame> q_;
  bool done_ = false;
  std::exception_ptr error_;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> given_{0}, delivered_{0}, dropped_{0}, skipped_{0};
  std::uint64_t passedWhilePaused_ = 0;  // the consumer's own
  IntervalCapture capture_;
  std::thread thread_;

  void push(AcquiredFrame&& f);
};

}  // namespace pp5::host

namespace pp5 {

template <>
struct EnumNames<host::DropPolicy> {
  static constexpr std::string_view key = "run.drop";
  static constexpr std::array<std::pair<host::DropPolicy, std::string_view>, 2> names{{
      {host::DropPolicy::Oldest, "oldest"},
      {host::DropPolicy::Newest, "newest"}}};
};

}  // namespace pp5
