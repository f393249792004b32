#include "host/run_loop.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <map>
#include <optional>
#include <thread>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "comm/transport.hpp"
#include "core/error.hpp"

namespace pp5::host {

namespace {

using Clock = std::chrono::steady_clock;
using comm::ControlMsg;

double msSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

class RunLoop {
public:
  RunLoop(Pipeline& p, const RunJob& j, const std::vector<Sink*>& sinks)
      : p_(p), j_(j), sinks_(sinks),
        state_(parallel::makeControlState(j.pipeline.render, j.pipeline.shading, j.pipeline.tf)) {
    for (Sink* s : sinks_)
      if (Steering* st = s->steering()) steer_ = st, steerSink_ = s;
    PipelineEvents e;
    e.frame = [this](const AcquiredFrame& a, std::uint64_t k) {
      for (Sink* s : sinks_) s->frame(a, k);
    };
    e.image = [this](const ImageView& im) {
      for (Sink* s : sinks_) s->image(im);
    };
    e.volume = [this](const Volume& v, const VolumeChange& c) {
      // Each sink is told where the volume may differ from the snapshot it
      // had last: the changes of the snapshots it was not given are kept for it.
      for (auto& [s, since] : changedSince_) since.add(c);
      for (Sink* s : volumeTo_) {
        const auto it = changedSince_.find(s);
        s->volume(v, volumeFrames_, it == changedSince_.end() ? VolumeChange{} : it->second);
        changedSince_[s] = VolumeChange{false, {}};
      }
      volumeTo_.clear();
    };
    e.stats = [this](const std::vector<double>& row) {
      for (Sink* s : sinks_) s->stats(row);
    };
    p_.setEvents(std::move(e));
  }

  int run();
  void serveVolume();

private:
  Pipeline& p_;
  const RunJob& j_;
  std::vector<Sink*> sinks_;
  Steering* steer_ = nullptr;
  Sink* steerSink_ = nullptr;
  std::vector<Sink*> volumeTo_;  // the sinks a snapshot on its way is for
  std::uint64_t volumeFrames_ = 0;  // ... and the frames it holds
  std::map<Sink*, VolumeChange> changedSince_;  // per sink given a snapshot: the changes since
  ViewState state_;              // what the pipeline renders now
  std::uint64_t frames_ = 0;
  const Acquisition* acq_ = nullptr;
  LiveWanted wanted_;
  std::uint64_t wantedVersion_ = 0;
  struct Sample {  // the counters every 250 ms, for the figures over the last two seconds
    Clock::time_point t;
    PipelineCounters c;
  };
  std::deque<Sample> window_;
  Clock::time_point lastFigures_{};

  bool interrupted() const { return j_.interrupt && j_.interrupt->load(); }

  // A control change; `wait`: its image is in (and checked) on return, as
  // the final images need; otherwise only where the pipeline is synchronous.
  void change(std::uint32_t changes, const ViewState& next, bool lasting, const std::string& what, bool wait) {
    const std::uint32_t epoch = p_.control(changes, next, lasting);
    state_ = next;
    for (Sink* s : sinks_) s->epochStarted(epoch, next, lasting);
    if (wait || p_.synchronous()) {
      p_.sync();
      if (!what.empty()) p_.verify(*p_.image().rgba, nullptr, what);
    }
  }

  // What the steering sink asks: a change (once the pipeline can take one,
  // so a drag does not queue views), an image, a volume for its slices; the
  // figures. True while it holds acquisition paused; `acted`: it did something.
  bool serveSteering(bool& acted) {
    if (askVolumes()) acted = true;
    if (Clock::now() - lastFigures_ > std::chrono::milliseconds(250)) publishFigures();
    if (!steer_) return false;
    if (steer_->version() != wantedVersion_) {  // fetched (under the viewer's lock) only when it changed
      wantedVersion_ = steer_->version();
      wanted_ = steer_->wanted();
    }
    if (const std::uint32_t ch = parallel::controlChanges(state_, wanted_.state); ch && p_.steerable()) {
      acted = true;
      change(ch, wanted_.state, true, frames_ > 0 ? "after a change from the viewer" : "", false);
    }
    if (steer_->wantsImage()) {
      acted = true;
      steerSink_->image(p_.image());
    }
    return wanted_.paused;
  }

  // The sinks that want a volume snapshot now: one request for them all (a
  // sink that asks while one is on its way joins it). True when it asked.
  bool askVolumes() {
    bool asked = false;
    for (Sink* s : sinks_)
      if (frames_ > 0 && s->wantsVolume() && std::find(volumeTo_.begin(), volumeTo_.end(), s) == volumeTo_.end()) {
        const bool first = volumeTo_.empty();
        volumeTo_.push_back(s);
        if (first) volumeFrames_ = frames_;
        if (first && p_.requestVolume()) asked = true;
      }
    return asked;
  }

  void publishFigures() {
    const auto now = Clock::now();
    lastFigures_ = now;
    const PipelineCounters c = p_.counters();
    window_.push_back({now, c});
    while (window_.size() > 9) window_.pop_front();
    const Sample& first = window_.front();
    LiveFigures f;
    const double span = std::chrono::duration<double>(now - first.t).count();
    if (span > 0) {
      f.framesPerS = static_cast<double>(c.frames - first.c.frames) / span;
      f.imagesPerS = static_cast<double>(c.images - first.c.images) / span;
      f.gpLoad = (c.gpBusyMs - first.c.gpBusyMs) / (1e3 * span * c.gps);
      f.ppLoad = (c.ppBusyMs - first.c.ppBusyMs) / (1e3 * span * c.pps);
    }
    f.latencyMedianMs = c.latencyMedianMs;
    f.latencyP95Ms = c.latencyP95Ms;
    f.frames = c.frames;
    f.dropped = acq_ ? acq_->dropped() : 0;
    for (Sink* s : sinks_) s->figures(f);
  }

  ImageView imageOf(const std::vector<float>& rgba) const {
    ImageView im = p_.image();
    im.rgba = &rgba;
    return im;
  }

  void finalImages();
  std::vector<double> orbit();
  void serveFinal();
};

void RunLoop::finalImages() {
  const ViewState liveState = state_;
  for (const pp::CompositeMode m : j_.pipeline.render.compositing) {
    const std::string what = fmt::format("final {} image", enumName(m));
    std::vector<float> im;
    if (compositesGreyValues(m) != compositesGreyValues(parallel::liveMode(state_))) {
      // The samples are of the other kind (colour or grey values): render this mode live.
      ViewState s = state_;
      s.liveMode = static_cast<std::uint8_t>(m);
      change(parallel::controlChanges(state_, s), s, false, "", true);
      im = *p_.image().rgba;
    } else {
      im = p_.composite(m);
    }
    p_.verify(im, &m, what);
    for (Sink* s : sinks_) s->finalImage(m, imageOf(im));
  }
  if (const std::uint32_t ch = parallel::controlChanges(state_, liveState))  // back to the live mode
    change(ch, liveState, false, "", true);
}

std::vector<double> RunLoop::orbit() {
  std::vector<double> ms;
  const ViewState base = state_;
  for (int i = 0; i < j_.orbitFrames; ++i) {
    ViewState s = base;
    s.orbitValid = 1;
    s.orbitDeg = 360.0 * i / j_.orbitFrames;
    const auto t0 = Clock::now();
    change(ControlMsg::kView, s, false, fmt::format("orbit view {}", i), true);
    ms.push_back(msSince(t0));
    for (Sink* sk : sinks_) sk->orbit(i, j_.orbitFrames, p_.image());
  }
  return ms;
}

// After the input: the user steers the final volume until Ctrl-C. Waits as
// the streaming loop does, so a drag's images go out at once; once the
// backoff is at its longest (the page idle a while), 5 ms sleeps, since this
// may go on for hours.
void RunLoop::serveFinal() {
  steer_->servingFinal();
  comm::IdleBackoff idle;
  while (!interrupted()) {
    bool acted = p_.poll();
    serveSteering(acted);
    if (acted) idle.reset();
    else if (idle.next() < comm::IdleBackoff::kLongest) idle.pause();
    else std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

void RunLoop::serveVolume() {
  RunStart rs{j_.grid, j_.pipeline.render.width, j_.pipeline.render.height, state_, p_.statsColumns()};
  for (Sink* s : sinks_) s->start(rs);
  const Volume& v = p_.volume();
  for (Sink* s : sinks_) s->volume(v, 0, VolumeChange{});
  for (Sink* s : sinks_) s->inputEnded();
  if (steer_) serveFinal();
}

int RunLoop::run() {
  const auto start = Clock::now();
  RunStart rs{j_.grid, j_.pipeline.render.width, j_.pipeline.render.height, state_, p_.statsColumns()};
  for (Sink* s : sinks_) s->start(rs);
  // Scripted changes by frame, in order.
  std::vector<ScriptedControl> script = j_.script;
  std::stable_sort(script.begin(), script.end(),
                   [](const ScriptedControl& a, const ScriptedControl& b) { return a.afterFrame < b.afterFrame; });
  std::size_t nextScript = 0;

  if (j_.source.prepare) j_.source.prepare();  // the simulated sweep's cache, before the pace's clock starts
  if (interrupted()) throw InputError("run: interrupted before the first frame");
  // Every part is ready before the first frame is acquired, so that a live
  // source does not queue behind the start-up.
  p_.start();
  // The source runs in its own thread into a bounded queue: paced at
  // run.pace_fps, cropped and subsampled, judged by the constant-interval
  // capture, and dropped by run.drop when a live (or paced) source gets
  // ahead of the pipeline; a file unpaced waits instead.
  Acquisition acq(j_.source, j_.preprocess, j_.queueFrames, j_.drop, j_.paceFps, j_.captureIntervalMm);
  acq_ = &acq;
  Clock::time_point firstAt{}, lastLog = start;
  std::optional<Clock::time_point> interruptedAt;  // set when interrupted: acquisition stopped
  comm::IdleBackoff idle;
  for (;;) {
    if (p_.poll()) idle.reset();
    bool acted = false;
    const bool paused = serveSteering(acted);
    if (acted) idle.reset();
    // Before the pause: Ctrl-C ends a paused run too. The frames queued and
    // taken so far go through the final passes and every output.
    if (!interruptedAt && interrupted()) {
      spdlog::warn("run: interrupted; finishing the {} frames taken and those still queued", frames_);
      acq.stop();
      interruptedAt = Clock::now();
    }
    if (paused && !interruptedAt) {
      if (!acq.whilePaused()) break;
      continue;
    }
    AcquiredFrame a;
    const auto wait = p_.frameWait(steer_ != nullptr);
    if (wait.count() > 0 ? acq.popFor(a, wait) : acq.tryPop(a)) {
      idle.reset();
      if (frames_ == 0) firstAt = Clock::now();
      const std::uint64_t sourceIndex = a.frame.index, k = frames_;
      p_.insert(a);
      ++frames_;
      // A snapshot the frame made due goes out right behind it, not after the
      // loop's next turn.
      askVolumes();
      if (p_.synchronous()) {
        p_.sync();
        p_.verify(*p_.image().rgba, nullptr, fmt::format("frame {}", k));
      }
      // By the source's frame index, so that dropped frames do not move the change.
      while (nextScript < script.size() && script[nextScript].afterFrame <= sourceIndex) {
        const ScriptedControl& sc = script[nextScript++];
        const std::uint32_t ch = parallel::controlChanges(state_, sc.state);
        if (!ch) continue;
        spdlog::info("run: after frame {}: {}", k, sc.text);
        change(ch, sc.state, true, fmt::format("after frame {} ({})", k, sc.text), false);
      }
      const auto now = Clock::now();
      if (now - lastLog > std::chrono::seconds(2)) {
        acq.logProgress(frames_, std::chrono::duration<double>(now - firstAt).count());
        lastLog = now;
      }
    } else if (acq.finished()) {
      break;
    } else if (wait.count() == 0) {
      idle.pause();
    }
  }
  if (frames_ == 0) throw InputError("run: the source gave no frame that can be placed");
  for (; nextScript < script.size(); ++nextScript)
    spdlog::warn("run: the source ended before frame {}; run.script entry \"{}\" was not applied",
                 script[nextScript].afterFrame, script[nextScript].text);
  p_.sync();
  const double streamS = std::chrono::duration<double>(Clock::now() - firstAt).count();
  publishFigures();  // every frame counted before the final images, which take a while
  for (Sink* s : sinks_) s->inputEnded();
  p_.settle();
  p_.streamEnded();

  // The end of the sweep: final passes, then what is shown of the final volume.
  change(ControlMsg::kFinish, state_, true, "after the final passes", true);
  for (Sink* s : sinks_) s->finished(p_.image());
  finalImages();
  bool wantVolume = p_.checksVolume();
  for (Sink* s : sinks_) wantVolume = wantVolume || s->wantsFinalVolume();
  if (wantVolume) {
    const Volume& v = p_.volume();
    for (Sink* s : sinks_) s->finalVolume(v);
  }
  RunEnd e;
  e.orbitMs = orbit();
  if (steer_ && steer_->servesFinal()) serveFinal();
  p_.settle();

  e.streamS = streamS;
  e.totalS = std::chrono::duration<double>(Clock::now() - start).count();
  e.dropped = acq.dropped();
  e.skipped = acq.skipped();
  e.captureIntervalMm = j_.captureIntervalMm;
  if (j_.source.statsJson) e.sourceStatsJson = j_.source.statsJson();
  const std::string summary = p_.end(e);
  for (Sink* s : sinks_) {
    if (!summary.empty()) s->summary(summary);
    s->ended();
  }
  acq.printCounts();
  // SIGTERM sent to mpirun reaches the host odls_base_sigkill_timeout seconds
  // before mpirun's SIGKILL (docs/cluster.md): say how long the ending took.
  if (interruptedAt)
    spdlog::info("run: every output written {:.2f} s after the interruption", msSince(*interruptedAt) / 1e3);
  std::printf("wrote to %s\n", std::filesystem::absolute(j_.outDir).string().c_str());
  for (Sink* s : sinks_)
    for (const auto& n : s->wrote()) std::printf("  %s\n", n.c_str());
  for (const auto& n : j_.alsoWrote) std::printf("  %s\n", n.c_str());
  return 0;
}

}  // namespace

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const auto i = static_cast<std::size_t>(std::ceil(q * static_cast<double>(v.size()))) - (q > 0 ? 1 : 0);
  return v[std::min(i, v.size() - 1)];
}

std::vector<double> FrameLatency::measured(std::size_t n) const {
  std::vector<double> out;
  for (std::size_t i = ms_.size(); i-- > 0 && (n == 0 || out.size() < n);)
    if (ms_[i] >= 0.0) out.push_back(ms_[i]);
  return out;
}

void FrameLatency::recent(PipelineCounters& c) const {
  const std::vector<double> last = measured(90);
  c.latencyMedianMs = percentile(last, 0.5);
  c.latencyP95Ms = percentile(last, 0.95);
}

serial::ViewStats applyControl(serial::SerialPipeline& pipe, std::uint32_t changes, const ViewState& next,
                  const RenderSettings& base, const Grid& grid) {
  RenderSettings render = base;
  gp::ShadeSettings shading = pipe.settings().shading;
  TransferFunctionSettings tf;
  parallel::applyControlState(next, render, shading, tf);
  if (changes & ControlMsg::kFinish) pipe.finish();
  if (changes & ControlMsg::kMode) pipe.setValueWindow(next.valueWindow[0], next.valueWindow[1]);
  if (changes & (ControlMsg::kShading | ControlMsg::kTransfer)) pipe.setStyle(shading, tf, parallel::liveMode(next));
  else if (changes & ControlMsg::kMode) pipe.setLiveMode(parallel::liveMode(next));
  if (changes & ControlMsg::kView)
    return pipe.setCamera(parallel::controlCamera(next, base, grid), next.stepScale, next.pixelStride);
  return {};
}

int runLoop(Pipeline& pipeline, const RunJob& job, const std::vector<Sink*>& sinks) {
  RunLoop loop(pipeline, job, sinks);
  return loop.run();
}

void serveVolume(Pipeline& pipeline, const RunJob& job, const std::vector<Sink*>& sinks) {
  RunLoop loop(pipeline, job, sinks);
  loop.serveVolume();
}

}  // namespace pp5::host
