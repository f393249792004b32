// What `pp5echo run` sets up before a run, from its settings: the checks
// every rank makes, the kernel derived from the frames, run.script, and the
// job both pipelines run.
#include "app/run_setup.hpp"

#include <algorithm>
#include <filesystem>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include "app/source_settings.hpp"
#include "reconstruction/recon_run.hpp"
#include "rendering/shading.hpp"
#include "analysis/speckle_run.hpp"
#include "sim/sweep_cache.hpp"
#include "core/error.hpp"
#include "core/io_util.hpp"
#include "host/capture.hpp"
#include "igtl/igtl_server.hpp"
#include "pipeline/parallel_settings.hpp"

namespace pp5::app {

namespace fs = std::filesystem;

host::Preprocess preprocessOf(const Settings& s) {
  host::Preprocess p;
  p.crop = glm::ivec4(s.run.cropOrigin, s.run.cropSize);
  if ((s.run.cropSize.x == 0) != (s.run.cropSize.y == 0))
    throw InputError("run.crop_size: give both a width and a height, or 0 0 for no crop");
  p.subsample = s.run.subsample;
  return p;
}


// Every rank reads the settings: what no stage could honour fails on all of
// them alike, before any rank starts.
void checkSettings(const Settings& s, bool outputDirGiven) {
  host::checkViewSettings(s.view);
  if (!s.igtl.serve.empty()) {
    std::string address;
    int port = 0;
    igtl::parseServeAddress(s.igtl.serve, "run.igtl_serve", address, port);
  }
  gp::checkReconSettings(s.recon);
  gp::checkShadeSettings(s.shading);
  s.cache.validate();
  if (s.parallel.tileSize % 8 != 0)
    throw InputError(fmt::format("parallel.tile_size = {}: use a multiple of 8", s.parallel.tileSize));
  (void)parseScript(s);
  if (s.run.source == SourceKind::Board || !s.board.armXTable.empty() || !s.board.armYTable.empty() ||
      !s.board.armThetaTable.empty())
    (void)armCalibration(s);
  if (s.output.dir.empty() && !outputDirGiven)
    throw InputError("output.dir is empty: name the folder the run writes into (or give -o DIR)");
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
  if (s.recon.tent.kernelFromFrames && !recorded)
    throw InputError(fmt::format(
        "recon.kernel_from_frames reads the frames before reconstructing them: `reconstruct`, `evaluate` and `run` "
        "with run.source = \"sequence\" (or the simulator's cached sweep) can; {} streams them as they come: "
        "measure a recording of the probe with `pp5echo evaluate speckle` and set the three recon.kernel_*_mm it "
        "prints",
        s.run.source == SourceKind::Simulator ? std::string("run.simulate_live = true")
                                              : fmt::format("run.source = \"{}\"", enumName(s.run.source))));
}

void warnUnusedSettings(const Settings& s, const ConfigSchema& schema, bool oneProcess) {
  // The settings only the distributed pipeline reads (parallel.threads and
  // the compositing tick are the serial pipeline's too).
  static const char* const kRanksOnly[] = {"parallel.gps",         "parallel.pps",        "parallel.gp_partition",
                                           "parallel.slab_split",  "parallel.ghost_voxels", "parallel.tile_size",
                                           "parallel.tile_owner",  "parallel.credits",    "parallel.batch_frames",
                                           "parallel.timeout_s"};
  std::vector<std::string> unused;
  if (oneProcess)
    for (const char* k : kRanksOnly)
      if (schema.assigned(k)) unused.emplace_back(k);
  if (!unused.empty())
    spdlog::warn("run: {} lay{} out the ranks of a run under mpirun; this one-process run does not use {}",
                 fmt::join(unused, ", "), unused.size() == 1 ? "s" : "", unused.size() == 1 ? "it" : "them");
  unused.clear();
  if (s.run.source != SourceKind::Board)
    for (const std::string& k : schema.assignedKeys())
      if (k.rfind("board.", 0) == 0) unused.push_back(k);
  if (!unused.empty())
    spdlog::warn("run: {} belong{} to run.source = \"board\"; this run's source is \"{}\" and does not use {}",
                 fmt::join(unused, ", "), unused.size() == 1 ? "s" : "", enumName(s.run.source),
                 unused.size() == 1 ? "it" : "them");
}

// recon.kernel_from_frames: the kernel from the recording (run.source =
// "sequence") or the simulator's cached sweep, printed, over the frames the
// host's constant-interval capture takes (a paced source that falls behind
// may drop others). Only where the source is read: rank 0 under mpirun, which
// sends it with the grid.
void deriveRunKernel(Settings& s, const ConfigSchema& schema) {
  if (!s.recon.tent.kernelFromFrames) return;
  std::string sequence = s.run.sequence, plusConfig = s.run.plusConfig;
  if (s.run.source == SourceKind::Simulator) {
    // The sweep the run streams, filled into the cache now rather than once the viewer's URL is out.
    spdlog::info("run: recon.kernel_from_frames: the simulated sweep first (from the cache, or simulated into it)");
    sim::SimulatedSweep sweep;
    try {
      sweep = sim::cachedSweep(s.sim, sweepGridOf(s), s.run.sweepCache);
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

// The job both pipelines run: the settings, the source and the grid it was
// given, and where the outputs go.
host::RunJob makeJob(const Settings& s, host::Source src, const Grid& grid, const std::string& dir,
                     const std::atomic<bool>* interrupt) {
  host::RunJob j;
  j.grid = grid;
  j.pipeline = {s.recon, s.render, s.shading, s.tf, s.cache};
  j.parallel = s.parallel;
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
  j.memoryLimitBytes = s.grid.memoryLimitBytes();
  j.interrupt = interrupt;
  j.view = s.view;
  j.igtl = s.igtl;
  j.plusConfig = s.run.plusConfig;
  j.alsoWrote = {"settings.toml"};
  return j;
}

void writeSettingsFile(const ConfigSchema& schema, const std::string& dir) {
  io::AtomicFile settingsFile((fs::path(dir) / "settings.toml").string());
  settingsFile.write(schema.toToml());
  settingsFile.commit();
}

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

}  // namespace pp5::app
