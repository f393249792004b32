// `pp5echo run CONFIG [--serial] -o DIR`: stream a source through every stage
// and write what a user sees: the build-up animation, the final images, a
// rotating loop, orthogonal slices, the volume and per-frame statistics.
// Without mpirun (and with --serial) it runs the single-process pipeline.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <deque>
#include <memory>
#include <numeric>
#include <optional>
#include <thread>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "app/commands.hpp"
#include "app/recon_run.hpp"
#include "app/settings.hpp"
#include "app/sources.hpp"
#include "app/speckle_run.hpp"
#include "app/sweep_cache.hpp"
#include "comm/mpi.hpp"
#include "core/error.hpp"
#include "core/image_io.hpp"
#include "core/io_util.hpp"
#include "core/volume_io.hpp"
#include "host/acquisition.hpp"
#include "host/capture.hpp"
#include "host/host_rank.hpp"
#include "host/live_view.hpp"
#include "host/outputs.hpp"
#include "parallel/parallel_settings.hpp"
#include "ranks/gp_rank.hpp"
#include "ranks/pp_rank.hpp"
#include "serial/serial_pipeline.hpp"
#include "sim/simulate.hpp"

namespace pp5::app {

namespace {

namespace fs = std::filesystem;

struct RunOptions {
  std::string file, outDir, source;
  std::vector<std::string> overrides;
  bool serial = false;
  std::string census;  // --census FILE (serial): where each frame's work lies, for bench --cost-model
  bool verify = false;
  std::string view;  // --view [ADDR:]PORT
  bool serve = false;
  int expectRanks = 0;
  int gps = -1, pps = -1;
};

using host::FrameSink;
using host::Source;

host::Preprocess preprocessOf(const Settings& s) {
  host::Preprocess p;
  p.crop = glm::ivec4(s.run.cropOrigin, s.run.cropSize);
  if ((s.run.cropSize.x == 0) != (s.run.cropSize.y == 0))
    throw InputError("run.crop_size: give both a width and a height, or 0 0 for no crop");
  p.subsample = s.run.subsample;
  return p;
}

std::atomic<bool> gInterrupted{false};
extern "C" void onInterrupt(int) { gInterrupted = true; }

// Every rank reads the settings: what no stage could honour fails on all of
// them alike, before any rank starts.
void checkSettings(const Settings& s) {
  host::checkViewSettings(s.view);
  gp::checkReconSettings(s.recon);
  // Not silently ignored: the pipeline takes every frame the acquisition gives it.
  if (s.recon.skipInterval > 1)
    throw InputError(fmt::format(
        "recon.skip_interval = {} applies to `reconstruct` and `evaluate` (PLUS's SkipInterval); `run` takes the "
        "frames its source gives: thin them with run.capture_interval_mm (a frame every so many mm)",
        s.recon.skipInterval));
  // The kernel is measured on the whole recording before the first frame goes
  // in; a live source (or the simulator) cannot be looked ahead in.
  const bool recorded = s.run.source == SourceKind::Sequence ||
                        (s.run.source == SourceKind::Simulator && !s.run.simulateLive);
  if (s.recon.kernelFromFrames && !recorded)
    throw InputError(fmt::format(
        "recon.kernel_from_frames reads the frames before reconstructing them: `reconstruct`, `evaluate` and `run` "
        "with run.source = \"sequence\" (or the simulator's cached sweep) can; {} streams them as they come: "
        "measure a recording of the probe with `pp5echo evaluate speckle` and set the three recon.kernel_*_mm it "
        "prints",
        s.run.source == SourceKind::Simulator ? std::string("run.simulate_live = true")
                                              : fmt::format("run.source = \"{}\"", enumName(s.run.source))));
}

// recon.kernel_from_frames: the kernel from the recording (run.source =
// "sequence") or the simulator's cached sweep, printed, over the frames the
// host's constant-interval capture takes (a paced source that falls behind
// may drop others). Only where the source is read: rank 0 under mpirun, which
// sends it with the grid.
void deriveRunKernel(Settings& s, const ConfigSchema& schema) {
  if (!s.recon.kernelFromFrames) return;
  std::string sequence = s.run.sequence, plusConfig = s.run.plusConfig;
  if (s.run.source == SourceKind::Simulator) {
    // The sweep the run streams, filled into the cache now rather than once the viewer's URL is out.
    spdlog::info("run: recon.kernel_from_frames: the simulated sweep first (from the cache, or simulated into it)");
    SimulatedSweep sweep;
    try {
      sweep = cachedSweep(s);
    } catch (const InputError& e) {
      throw InputError(fmt::format("recon.kernel_from_frames measures the simulated sweep in its cache: {}; set "
                                   "run.sweep_cache to a folder that can be written, or set the kernel by hand",
                                   e.what()));
    }
    sequence = sweep.sequencePath;
    plusConfig = sweep.configPath;
  }
  const PosedSequence seq = openPosedSequence(sequence, plusConfig);
  // The capture judges each frame after the crop and subsampling, which move
  // its pixel grid by the same matrix whatever the pose.
  const SequenceInfo& info = seq.reader->info();
  Frame size;
  size.allocate(info.width, info.height, PixelType::U8);
  Mat4 afterPreprocess(1.0);
  host::preprocess(preprocessOf(s), size, afterPreprocess);
  host::IntervalCapture capture(s.run.captureIntervalMm);
  std::vector<std::uint8_t> taken(seq.poses.size(), 0);
  for (std::size_t i = 0; i < seq.poses.size(); ++i)
    if (seq.poses[i]) taken[i] = capture.take(size, *seq.poses[i] * afterPreprocess) ? 1 : 0;
  // The pixels inserted are the subsampled ones: the in-plane reach is at least twice theirs.
  const glm::dvec2 scale(glm::length(Vec3(afterPreprocess[0])), glm::length(Vec3(afterPreprocess[1])));
  deriveKernelFromFrames(seq, s.recon, schema, [&taken](std::uint64_t i) { return taken[i] != 0; }, scale);
}

// The serial run's side of the live viewer: what the host rank does for the
// distributed pipeline, for the one process.
class SerialViewer {
public:
  SerialViewer(const Settings& s, const Grid& grid, serial::SerialPipeline& pipe, const std::string& dir)
      : s_(s), grid_(grid), pipe_(pipe), cur_(parallel::makeControlState(s.render, s.shading, s.tf)) {
    if (s.view.listen.empty()) return;
    live_ = std::make_unique<host::LiveView>(s.view, grid, s.render, s.recon, s.tf, cur_, dir);
    std::printf("viewer: open %s\n", live_->url().c_str());
    std::fflush(stdout);
  }
  explicit operator bool() const { return live_ != nullptr; }
  host::LiveView& live() { return *live_; }
  // The view's epoch: 0, then one more for each change (run.script's or the page's).
  std::uint32_t epoch() const { return epoch_; }
  // The acquisition's drop counter, for the page's figures.
  void countDrops(std::function<std::uint64_t()> dropped) { dropped_ = std::move(dropped); }

  // A run.script change: the pipeline takes it, and the page's next changes
  // start from it (as the host rank does under mpirun). A change is a new
  // epoch, with or without a page, as on the host; an entry that changes
  // nothing is none.
  void scripted(const comm::ControlState& next) {
    const std::uint32_t ch = parallel::controlChanges(cur_, next);
    if (!ch) return;
    host::applyControl(pipe_, ch, next, s_.render, grid_);
    cur_ = next;
    ++epoch_;
    if (!live_) return;
    live_->epochStarted(epoch_, cur_);
    live_->image(pipe_.image().rgba, pipe_.image().width, pipe_.image().height, epoch_,
                 static_cast<std::int64_t>(frames_) - 1);
  }

  void frame(const Frame& f, const Mat4& pose, double t, std::chrono::steady_clock::time_point arrival, double ms) {
    if (!live_) return;
    live_->frame(f, pose, frames_, t, arrival);
    ++frames_;
    frameMs_.push_back(ms);
    live_->image(pipe_.image().rgba, pipe_.image().width, pipe_.image().height, epoch_,
                 static_cast<std::int64_t>(frames_) - 1);
  }

  // Applies what the page asks; true while it asks for a pause.
  bool serve() {
    if (!live_) return false;
    const host::LiveWanted w = live_->wanted();
    if (const std::uint32_t ch = parallel::controlChanges(cur_, w.state)) {
      host::applyControl(pipe_, ch, w.state, s_.render, grid_);
      cur_ = w.state;
      live_->epochStarted(++epoch_, cur_);
      live_->image(pipe_.image().rgba, pipe_.image().width, pipe_.image().height, epoch_,
                   static_cast<std::int64_t>(frames_) - 1);
    }
    if (live_->wantsImage())
      live_->image(pipe_.image().rgba, pipe_.image().width, pipe_.image().height, epoch_,
                   static_cast<std::int64_t>(frames_) - 1);
    if (frames_ > 0 && live_->wantsVolume()) live_->volume(pipe_.reconstructor().output());
    const auto now = std::chrono::steady_clock::now();
    if (now - lastFigures_ > std::chrono::milliseconds(250)) {
      window_.emplace_back(now, frames_);
      while (window_.size() > 9) window_.pop_front();
      lastFigures_ = now;
      host::LiveFigures f;
      const double span = std::chrono::duration<double>(now - window_.front().first).count();
      if (span > 0) f.framesPerS = f.imagesPerS = static_cast<double>(frames_ - window_.front().second) / span;
      std::vector<double> last(frameMs_.end() - std::min<std::ptrdiff_t>(90, std::ssize(frameMs_)), frameMs_.end());
      std::sort(last.begin(), last.end());
      if (!last.empty()) {
        f.latencyMedianMs = last[last.size() / 2];
        f.latencyP95Ms = last[std::min(last.size() - 1, static_cast<std::size_t>(0.95 * last.size()))];
      }
      f.frames = frames_;
      f.dropped = dropped_ ? dropped_() : 0;
      f.gpLoad = f.ppLoad = 1.0;  // one process does it all
      live_->figures(f);
    }
    return w.paused;
  }

  void ended() {
    if (!live_) return;
    lastFigures_ = {};  // every frame counted at once
    live_->inputEnded();
    serve();
  }

  // After the input: the page steers the final volume until Ctrl-C.
  void serveFinal() {
    if (!live_ || !live_->serve()) return;
    live_->servingFinal();
    std::printf("viewer: the final volume stays live at %s until Ctrl-C\n", live_->url().c_str());
    std::fflush(stdout);
    while (!gInterrupted) {
      serve();
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  }

private:
  const Settings& s_;
  Grid grid_;
  serial::SerialPipeline& pipe_;
  comm::ControlState cur_;
  std::unique_ptr<host::LiveView> live_;
  std::uint32_t epoch_ = 0;
  std::uint64_t frames_ = 0;
  std::vector<double> frameMs_;
  std::deque<std::pair<std::chrono::steady_clock::time_point, std::uint64_t>> window_;
  std::chrono::steady_clock::time_point lastFigures_{};
  std::function<std::uint64_t()> dropped_;
};

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

std::vector<host::ScriptedControl> parseScript(const Settings& base);

// A run writes its settings to DIR/settings.toml. Started from that very file
// (re-running a saved run in its own folder), it leaves the file as it is,
// which already says everything; with overrides it would replace the user's
// file, comments and all, so it is refused before anything is touched.
// Returns whether the run writes DIR/settings.toml.
bool checkSettingsFileTarget(const std::vector<std::string>& overrides, const std::string& file, const std::string& dir) {
  std::error_code ec;
  const fs::path out = fs::path(dir) / "settings.toml";
  if (file.empty() || !fs::exists(out, ec) || !fs::equivalent(file, out, ec)) return true;
  if (!overrides.empty())
    throw InputError(fmt::format("{}: the run would write its settings, with the --set overrides, over this "
                                 "configuration file; give another output folder (-o)",
                                 file));
  return false;
}

int runSerial(const RunOptions& o) {
  Settings s;
  ConfigSchema schema;
  registerAll(schema, s);
  loadSettings(schema, o.file, o.overrides);
  checkSettings(s);
  const std::string dir = o.outDir.empty() ? s.output.dir : o.outDir;
  const bool writeSettings = checkSettingsFileTarget(o.overrides, o.file, dir);
  deriveRunKernel(s, schema);
  host::RunFolder folder(dir);
  std::signal(SIGINT, onInterrupt);
  std::signal(SIGTERM, onInterrupt);

  Source src = makeSource(s);
  serial::PipelineSettings ps{s.recon, s.render, s.shading, s.tf, s.cache};
  spdlog::info("run: {}; grid {}x{}x{} of {} mm; {}x{} image, {} composition", src.description, src.grid.dims.x,
               src.grid.dims.y, src.grid.dims.z, src.grid.spacing.x, s.render.width, s.render.height,
               enumName(s.render.compositing.front()));
  serial::SerialPipeline pipe(src.grid, ps, s.grid.memoryLimitBytes());
  spdlog::info("run: ray cache {:.1f} MiB ({} samples, {} format), shade buffer {:.1f} MiB",
               static_cast<double>(pipe.cache().memoryBytes()) / (1 << 20), pipe.cache().sampleCount(),
               pp::sampleFormatName(pipe.cache().format()),
               static_cast<double>(pipe.shadeBuffer().memoryBytes()) / (1 << 20));
  std::unique_ptr<serial::WorkCensus> census;
  if (!o.census.empty()) {
    census = std::make_unique<serial::WorkCensus>(src.grid, s.render.width, s.render.height);
    pipe.setCensus(census.get());
  }
  SerialViewer viewer(s, src.grid, pipe, dir);
  // run.script: by the source's frame index, as under mpirun.
  std::vector<host::ScriptedControl> script = parseScript(s);
  std::stable_sort(script.begin(), script.end(),
                   [](const host::ScriptedControl& a, const host::ScriptedControl& b) { return a.afterFrame < b.afterFrame; });
  // Everything that could refuse the run has passed: the folder is the run's now.
  folder.start({o.file, o.census});
  if (writeSettings) {
    io::AtomicFile settingsFile((fs::path(dir) / "settings.toml").string());
    settingsFile.write(schema.toToml());
    settingsFile.commit();
  }
  std::size_t nextScript = 0;
  const int w = s.render.width, h = s.render.height;
  host::StatsCsv stats((fs::path(dir) / "stats.csv").string(),
                       {"frame", "epoch", "recon_ms", "shade_ms", "sample_ms", "composite_ms", "total_ms", "fill_in_slices",
                        "dirty_bricks", "dirty_voxels", "shaded_voxels", "dbuffer_rays", "samples", "rays_composited",
                        "blocks_composited"});
  AnimatedGif buildup((fs::path(dir) / "buildup.gif").string(), w, h, s.run.buildupFps);
  std::vector<double> totals, recons, shades, samplings, composites;
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  auto lastLog = start;
  std::uint64_t done = 0;
  // The source runs in its own thread into a bounded queue, as on the host
  // rank under mpirun: paced at run.pace_fps, cropped and subsampled, judged
  // by the constant-interval capture, and dropped by run.drop when a live (or
  // paced) source gets ahead of the pipeline; a file unpaced waits instead.
  if (src.prepare) src.prepare();  // the simulated sweep's cache, before the pace's clock starts
  if (gInterrupted) throw InputError("run: interrupted before the first frame");
  host::Acquisition acq(src, preprocessOf(s), static_cast<std::size_t>(s.run.queueFrames), s.run.drop, s.run.paceFps,
                        s.run.captureIntervalMm);
  viewer.countDrops([&acq] { return acq.dropped(); });
  bool interrupted = false;
  Clock::time_point firstAt{};
  const auto process = [&](const host::AcquiredFrame& a) {
    if (done == 0) firstAt = Clock::now();
    const Frame& f = a.frame;
    const Mat4& pose = a.imageToReference;
    const serial::FrameStats st = pipe.insert(f, pose, a.timeS);
    stats.row({static_cast<double>(st.index), static_cast<double>(viewer.epoch()), st.reconMs, st.shadeMs,
               st.sampleMs, st.compositeMs, st.totalMs(),
               static_cast<double>(st.fillInSlices), static_cast<double>(st.dirtyBricks),
               static_cast<double>(st.dirtyVoxels), static_cast<double>(st.shadedVoxels),
               static_cast<double>(st.dbufferPixels), static_cast<double>(st.samples),
               static_cast<double>(st.raysComposited), static_cast<double>(st.blocksComposited)});
    totals.push_back(st.totalMs());
    recons.push_back(st.reconMs);
    shades.push_back(st.shadeMs);
    samplings.push_back(st.sampleMs);
    composites.push_back(st.compositeMs);
    // The latency from the frame's arrival, its wait in the queue included.
    viewer.frame(f, pose, a.timeS, a.arrival,
                 std::chrono::duration<double, std::milli>(Clock::now() - a.arrival).count());
    if (done % static_cast<std::uint64_t>(s.run.buildupEvery) == 0) buildup.add(pp::toRgb8(pipe.image()).data());
    // By the source's frame index, so that dropped frames do not move the change.
    while (nextScript < script.size() && script[nextScript].afterFrame <= f.index) {
      const host::ScriptedControl& sc = script[nextScript++];
      spdlog::info("run: after frame {}: {}", done, sc.text);
      viewer.scripted(sc.state);
    }
    ++done;
    const auto now = Clock::now();
    if (now - lastLog > std::chrono::seconds(2)) {
      acq.logProgress(done, std::chrono::duration<double>(now - firstAt).count());
      lastLog = now;
    }
  };
  for (;;) {
    // Ctrl-C or SIGTERM: the source stops, and the frames queued and taken so
    // far go through the final passes and every output, as under mpirun.
    if (!interrupted && gInterrupted) {
      spdlog::warn("run: interrupted; finishing the {} frames taken and those still queued", done);
      acq.stop();
      interrupted = true;
    }
    if (viewer.serve() && !interrupted) {
      if (!acq.whilePaused()) break;
      continue;
    }
    // Waits on the queue; the page is served at least every 5 ms while one is open.
    host::AcquiredFrame a;
    if (acq.popFor(a, std::chrono::milliseconds(viewer ? 5 : 50))) process(a);
    else if (acq.finished()) break;
  }
  if (done == 0) throw InputError("run: the source gave no frame that can be placed");
  for (; nextScript < script.size(); ++nextScript)
    spdlog::warn("run: the source ended before frame {}; run.script entry \"{}\" was not applied",
                 script[nextScript].afterFrame, script[nextScript].text);

  if (census) {
    pipe.setCensus(nullptr);
    census->write(o.census);
    spdlog::info("run: the census of {} frames is in {}", census->frames(), o.census);
  }
  // The end of the sweep: final passes, then what is shown of the final volume.
  pipe.finish();
  viewer.ended();
  buildup.add(pp::toRgb8(pipe.image()).data());
  buildup.close();
  std::vector<std::string> wrote = {"buildup.gif"};
  const pp::CompositeMode liveMode = pipe.liveMode();
  for (const pp::CompositeMode m : s.render.compositing) {
    const std::string mode(enumName(m));
    // MIP and additive need grey-value samples, over classified colour ones.
    if (compositesGreyValues(m) != compositesGreyValues(pipe.liveMode())) pipe.setLiveMode(m);
    const pp::TileImage im = m == pipe.liveMode() ? pipe.image() : pipe.compositeFull(m);
    const std::string name = "final_" + mode + ".png";
    writeRgbPng((fs::path(dir) / name).string(), w, h, pp::toRgb8(im).data());
    wrote.push_back(name);
  }
  pipe.setLiveMode(liveMode);
  if (s.run.mpr) {
    for (const auto& p : host::writeMpr(pipe.reconstructor().output(), s.run.mprLook, (fs::path(dir) / "mpr").string()))
      wrote.push_back(fs::path(p).filename().string());
  }
  if (s.run.volume) {
    writeVolume((fs::path(dir) / "volume.mha").string(), pipe.reconstructor().output().as(ScalarType::U8), true);
    wrote.push_back("volume.mha");
  }
  double orbitMs = 0.0;
  std::vector<serial::ViewStats> orbitStats;
  if (s.run.orbitFrames > 0) {
    AnimatedGif orbit((fs::path(dir) / "orbit.gif").string(), w, h, s.run.orbitFps);
    const Camera base = pipe.camera();
    std::vector<double> ms;
    for (int i = 0; i < s.run.orbitFrames; ++i) {
      const auto t = Clock::now();
      orbitStats.push_back(pipe.setCamera(base.orbited(Vec3(0, 0, 1), 360.0 * i / s.run.orbitFrames)));
      ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t).count());
      orbit.add(pp::toRgb8(pipe.image()).data());
    }
    orbit.close();
    orbitMs = median(ms);
    wrote.push_back("orbit.gif");
  }
  wrote.push_back("stats.csv");
  wrote.push_back("settings.toml");
  viewer.serveFinal();

  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  std::printf("run: %llu frames through the serial pipeline in %.1f s\n", static_cast<unsigned long long>(done),
              seconds);
  std::printf("  per frame (median): %.1f ms = reconstruct %.1f + shade %.1f + sample %.1f + composite %.1f\n",
              median(totals), median(recons), median(shades), median(samplings), median(composites));
  if (orbitMs > 0.0) {
    auto med = [&](double serial::ViewStats::*f) {
      std::vector<double> v;
      for (const auto& o : orbitStats) v.push_back(o.*f);
      return median(v);
    };
    std::printf("  full re-render after a view change (median of %zu): %.0f ms = lattice %.1f + cache reset %.1f + "
                "re-light %.1f + sample and put %.1f + composite %.1f\n",
                orbitStats.size(), orbitMs, med(&serial::ViewStats::latticeMs), med(&serial::ViewStats::cacheMs),
                med(&serial::ViewStats::shadeMs), med(&serial::ViewStats::sampleMs),
                med(&serial::ViewStats::compositeMs));
  }
  acq.printCounts();
  folder.finished();
  std::printf("wrote to %s\n", fs::absolute(dir).string().c_str());
  for (const auto& n : wrote) std::printf("  %s\n", n.c_str());
  return 0;
}


// ---- the distributed pipeline (under mpirun) --------------------------------


// run.script entries: "AFTER_FRAME key = value; key = value".
std::vector<host::ScriptedControl> parseScript(const Settings& base) {
  std::vector<host::ScriptedControl> out;
  Settings cur = base;
  ConfigSchema schema;
  registerAll(schema, cur);
  static const std::vector<std::string> allowed = {"render.azimuth_deg", "render.elevation_deg", "render.distance",
                                                   "render.projection", "render.fov_deg", "render.compositing"};
  for (std::size_t i = 0; i < base.run.script.size(); ++i) {
    const std::string& e = base.run.script[i];
    const std::string what = fmt::format("run.script[{}] = \"{}\"", i, e);
    std::size_t pos = 0;
    unsigned long long frame = 0;
    try {
      frame = std::stoull(e, &pos);
    } catch (const std::exception&) {
      throw InputError(what + ": it must start with the frame number after which the change applies");
    }
    std::string rest = e.substr(pos);
    std::size_t start = 0;
    bool any = false;
    while (start <= rest.size()) {
      const std::size_t end = std::min(rest.find(';', start), rest.size());
      std::string a = rest.substr(start, end - start);
      a.erase(0, a.find_first_not_of(" \t"));
      a.erase(a.find_last_not_of(" \t") + 1);
      start = end + 1;
      if (a.empty()) continue;
      std::string key = a.substr(0, a.find('='));
      key.erase(key.find_last_not_of(" \t") + 1);
      const bool ok = std::find(allowed.begin(), allowed.end(), key) != allowed.end() ||
                      key.rfind("render.shading.", 0) == 0 || key.rfind("render.tf.", 0) == 0;
      if (!ok)
        throw InputError(fmt::format("{}: \"{}\" cannot change during a run (view, shading, transfer function and "
                                     "render.compositing can)",
                                     what, key));
      try {
        schema.set(a);
      } catch (const InputError& err) {
        throw InputError(what + ": " + err.what());
      }
      any = true;
    }
    if (!any) throw InputError(what + ": no change given after the frame number");
    out.push_back({frame, parallel::makeControlState(cur.render, cur.shading, cur.tf), e});
  }
  return out;
}

int runDistributed(const RunOptions& o) {
  const comm::MpiSession mpi;
  const int rank = mpi.rank(), size = mpi.size();
  std::signal(SIGINT, onInterrupt);
  std::signal(SIGTERM, onInterrupt);
  std::signal(SIGUSR1, onInterrupt);  // what scripts/mpirun.sh turns Ctrl-C into (mpirun forwards it)
  const char* role = "host";
  Settings s;
  ConfigSchema schema;
  parallel::RankLayout layout;
  bool writeSettings = true;
  try {
    registerAll(schema, s);
    std::vector<std::string> overrides = o.overrides;
    if (o.gps >= 0) overrides.push_back(fmt::format("parallel.gps={}", o.gps));
    if (o.pps >= 0) overrides.push_back(fmt::format("parallel.pps={}", o.pps));
    loadSettings(schema, o.file, overrides);
    checkSettings(s);
    if (o.expectRanks > 0 && size != o.expectRanks)
      throw InputError(fmt::format("--expect-ranks {}: the job has {} ranks (was it started by another MPI's "
                                   "launcher?)",
                                   o.expectRanks, size));
    layout = parallel::RankLayout::choose(size, s.parallel.gps, s.parallel.pps);
    if (s.parallel.tileSize % 8 != 0)
      throw InputError(fmt::format("parallel.tile_size = {}: use a multiple of 8", s.parallel.tileSize));
    (void)parseScript(s);  // a bad run.script is refused here, before the output folder is touched
    writeSettings = checkSettingsFileTarget(overrides, o.file, o.outDir.empty() ? s.output.dir : o.outDir);
  } catch (const std::exception& e) {
    // Every rank reads the same configuration and fails the same way: one message.
    if (rank == 0) comm::abortJob(rank, role, e.what());
    comm::abortJobQuietly();
  }
  role = parallel::roleName(layout.role(rank));
  int status = 0;
  try {
    const std::unique_ptr<comm::Transport> transport = mpi.transport(s.parallel.timeoutS);
    comm::Transport& t = *transport;
    const std::string dir = o.outDir.empty() ? s.output.dir : o.outDir;
    host::Source src;
    comm::GridMsg gm;
    gm.h.tag = comm::kTagGrid;
    std::optional<host::RunFolder> folder;
    if (rank == 0) {
      folder.emplace(dir);
      src = makeSource(s);
      deriveRunKernel(s, schema);
      for (int a = 0; a < 3; ++a) {
        gm.dims[a] = src.grid.dims[a];
        gm.origin[a] = src.grid.origin[a];
        gm.spacing[a] = src.grid.spacing[a];
      }
      gm.kernelMm[0] = s.recon.kernelLateralMm;
      gm.kernelMm[1] = s.recon.kernelAxialMm;
      gm.kernelMm[2] = s.recon.kernelElevationMm;
    }
    t.broadcast(gm, 0);
    Grid grid;
    for (int a = 0; a < 3; ++a) {
      grid.dims[a] = gm.dims[a];
      grid.origin[a] = gm.origin[a];
      grid.spacing[a] = gm.spacing[a];
    }
    // Every rank reconstructs, or reaches, with the host's kernel (derived there, or as read by all).
    s.recon.kernelLateralMm = gm.kernelMm[0];
    s.recon.kernelAxialMm = gm.kernelMm[1];
    s.recon.kernelElevationMm = gm.kernelMm[2];
    switch (layout.role(rank)) {
      case parallel::Role::Host: {
        host::HostJob j;
        j.grid = grid;
        j.pipeline = {s.recon, s.render, s.shading, s.tf, s.cache};
        j.parallel = s.parallel;
        j.layout = layout;
        j.source = std::move(src);
        j.preprocess = preprocessOf(s);
        j.queueFrames = static_cast<std::size_t>(s.run.queueFrames);
        j.drop = s.run.drop;
        j.paceFps = s.run.paceFps;
        j.captureIntervalMm = s.run.captureIntervalMm;
        j.script = parseScript(s);
        j.outDir = dir;
        j.buildupEvery = s.run.buildupEvery;
        j.buildupFps = s.run.buildupFps;
        j.orbitFrames = s.run.orbitFrames;
        j.orbitFps = s.run.orbitFps;
        j.mpr = s.run.mpr;
        j.mprLook = s.run.mprLook;
        j.volume = s.run.volume;
        j.verify = o.verify;
        j.memoryLimitBytes = s.grid.memoryLimitBytes();
        j.interrupt = &gInterrupted;
        j.view = s.view;
        spdlog::info("run: {}; grid {}x{}x{} of {} mm; {}x{} image; {} ranks: 1 host, {} GP ({} partition), {} PP "
                     "({} tiles of {} px), compositing on {}",
                     j.source.description, grid.dims.x, grid.dims.y, grid.dims.z, grid.spacing.x, s.render.width,
                     s.render.height, size, layout.gps, enumName(s.parallel.gpPartition), layout.pps,
                     enumName(s.parallel.tileOwner), s.parallel.tileSize, enumName(s.parallel.compositeOn));
        folder->start({o.file});  // the settings and the source have passed: the folder is the run's now
        if (writeSettings) {
          io::AtomicFile settingsFile((fs::path(dir) / "settings.toml").string());
          settingsFile.write(schema.toToml());
          settingsFile.commit();
        }
        status = host::runHostRank(t, j);
        if (status == 0) folder->finished();
        break;
      }
      case parallel::Role::Gp: {
        ranks::GpRankConfig c{grid,   s.recon, s.render, s.shading, s.tf, s.parallel, layout, s.grid.memoryLimitBytes(),
                              pp::sampleWireFor(s.cache.format)};
        ranks::runGpRank(t, c);
        break;
      }
      case parallel::Role::Pp: {
        ranks::PpRankConfig c{grid, s.render, s.shading, s.tf, s.cache, s.parallel, layout};
        ranks::runPpRank(t, c);
        break;
      }
    }
  } catch (const std::exception& e) {
    comm::abortJob(rank, role, e.what());
  }
  return status;
}

int runCommand(const RunOptions& o) {
  if (o.serial || !comm::launchedByMpi()) {
    if (o.verify) throw InputError("--verify compares the distributed pipeline with the serial one; run it under mpirun");
    if (o.expectRanks > 1)
      throw InputError(fmt::format("--expect-ranks {}: this process was not started by mpirun", o.expectRanks));
    return runSerial(o);
  }
  if (!o.census.empty()) throw InputError("--census counts the serial pipeline's work; add --serial");
  return runDistributed(o);
}

}  // namespace

namespace {
void addRunOptions(CLI::App* cmd, const std::shared_ptr<RunOptions>& o) {
  cmd->add_option("CONFIG", o->file, "TOML configuration (optional)");
  cmd->add_option("-o,--output", o->outDir, "Output folder (default: output.dir)");
  cmd->add_option("--set", o->overrides, "Override an option: key=value (repeatable)");
  cmd->add_option("--source", o->source,
                  "board | igtl://HOST:PORT | sequence | simulator (overrides run.source and run.igtl_url)");
  cmd->add_flag("--serial", o->serial, "Run the single-process pipeline (what runs without mpirun)");
  cmd->add_option("--census", o->census,
                  "Serial run: write where each frame's work lies (by grid layer and screen bin) to this JSON file, "
                  "the input of `bench --cost-model`");
  cmd->add_option("--gps", o->gps, "Graphics processors (overrides parallel.gps)")->check(CLI::Range(0, 4096));
  cmd->add_option("--pps", o->pps, "Pixel processors (overrides parallel.pps)")->check(CLI::Range(0, 4096));
  cmd->add_flag("--verify", o->verify,
                "Under mpirun: also run the serial pipeline on the host and require its images to be bitwise equal: "
                "every image in lockstep; in tick mode the image once every frame is in, and those after it");
  cmd->add_option("--expect-ranks", o->expectRanks, "Refuse to run unless the job has exactly this many ranks");
  cmd->add_option("--view", o->view,
                  "Serve the live viewer at [ADDR:]PORT (address 127.0.0.1 unless given; sets view.listen); its URL is "
                  "printed first");
  cmd->add_flag("--serve", o->serve,
                "Keep the final volume interactive in the viewer after the input ends, until Ctrl-C (view.serve)");
}

// `pp5echo view VOLUME.mha`: any volume (one pp5echo or PLUS wrote) in the
// live viewer, rendered like a reconstructed one, until Ctrl-C.
int viewVolume(const std::string& file, const std::string& config, const std::vector<std::string>& overrides,
               const std::string& listen) {
  Settings s;
  ConfigSchema schema;
  registerAll(schema, s);
  loadSettings(schema, config, overrides);
  if (!listen.empty()) s.view.listen = listen;
  if (s.view.listen.empty()) s.view.listen = "127.0.0.1:8080";
  s.view.serve = true;
  std::signal(SIGINT, onInterrupt);
  std::signal(SIGTERM, onInterrupt);
  const Volume v = readVolume(file);
  spdlog::info("view: {}: {}x{}x{} voxels of {} x {} x {} mm", file, v.grid.dims.x, v.grid.dims.y, v.grid.dims.z,
               v.grid.spacing.x, v.grid.spacing.y, v.grid.spacing.z);
  serial::SerialPipeline pipe(v, serial::PipelineSettings{s.recon, s.render, s.shading, s.tf, s.cache});
  SerialViewer viewer(s, v.grid, pipe, s.output.dir);
  viewer.live().volume(pipe.reconstructor().output());
  viewer.ended();
  viewer.serveFinal();
  return 0;
}

// --source becomes overrides placed before the user's own --set ones.
int runWithSource(RunOptions o, const std::string& record) {
  std::vector<std::string> extra;
  if (!o.source.empty()) extra = sourceOverrides(o.source);
  if (!record.empty()) extra.push_back(fmt::format("run.record=\"{}\"", record));
  if (!o.view.empty()) extra.push_back(fmt::format("view.listen=\"{}\"", o.view));
  if (o.serve) extra.push_back("view.serve=true");
  o.overrides.insert(o.overrides.begin(), extra.begin(), extra.end());
  return runCommand(o);
}
}  // namespace

void addRunCommand(CLI::App& app, int& exitCode) {
  auto o = std::make_shared<RunOptions>();
  auto* cmd = app.add_subcommand("run", "Stream a source (simulator, sequence, board, OpenIGTLink) through every stage "
                                        "and write the images");
  addRunOptions(cmd, o);
  cmd->callback([o, &exitCode] { exitCode = runWithSource(*o, ""); });

  struct ViewOptions {
    std::string file, config, listen;
    std::vector<std::string> overrides;
  };
  auto vo = std::make_shared<ViewOptions>();
  auto* vcmd = app.add_subcommand("view", "Open a volume (.mha, .nrrd; one pp5echo or PLUS wrote) in the live viewer, "
                                          "until Ctrl-C");
  vcmd->add_option("VOLUME", vo->file, "The volume")->required();
  vcmd->add_option("-c,--config", vo->config, "TOML configuration for the rendering (optional)");
  vcmd->add_option("--set", vo->overrides, "Override an option: key=value (repeatable)");
  vcmd->add_option("--view", vo->listen, "Serve at [ADDR:]PORT (default view.listen, else 127.0.0.1:8080)");
  vcmd->callback([vo, &exitCode] { exitCode = viewVolume(vo->file, vo->config, vo->overrides, vo->listen); });

  auto r = std::make_shared<RunOptions>();
  auto rec = std::make_shared<std::string>();
  auto* rcmd = app.add_subcommand("record", "Like run, and write every acquired frame to a PLUS sequence file as it "
                                            "arrives (OUT/recording.mha), so that nothing acquired is lost");
  addRunOptions(rcmd, r);
  rcmd->add_option("--file", *rec, "The sequence file to write (default: OUTPUT/recording.mha)");
  rcmd->callback([r, rec, &exitCode] {
    std::string path = *rec;
    if (path.empty()) {
      // The output folder as run resolves it: -o, else output.dir from the configuration.
      const Settings s = readSettings(r->file, r->overrides);
      path = (fs::path(r->outDir.empty() ? s.output.dir : r->outDir) / "recording.mha").string();
    }
    exitCode = runWithSource(*r, path);
  });
}

}  // namespace pp5::app
