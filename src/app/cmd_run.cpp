// `pp5echo run CONFIG [--serial] -o DIR`: stream a source through every stage
// and write what a user sees: the build-up animation, the final images, a
// rotating loop, orthogonal slices, the volume and per-frame statistics.
// Without mpirun (and with --serial) it runs the single-process pipeline.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <numeric>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "app/commands.hpp"
#include "app/recon_run.hpp"
#include "app/settings.hpp"
#include "core/error.hpp"
#include "core/image_io.hpp"
#include "core/io_util.hpp"
#include "core/volume_io.hpp"
#include "host/outputs.hpp"
#include "host/serial_pipeline.hpp"
#include "sim/simulate.hpp"

namespace pp5::app {

namespace {

namespace fs = std::filesystem;

struct RunOptions {
  std::string file, outDir;
  std::vector<std::string> overrides;
  bool serial = false;
};

// A source hands frames, with their ImageToReference and time, to `sink` in order.
using FrameSink = std::function<void(const Frame&, const Mat4&, double)>;

struct Source {
  std::string description;
  std::uint64_t frames = 0;
  Grid grid;
  std::function<void(const FrameSink&)> run;
};

Source simulatorSource(const Settings& s) {
  auto sim = std::make_shared<sim::SweepSimulator>(s.sim);
  Source src;
  src.frames = sim->frameCount();
  if (src.frames == 0)
    throw InputError("sim.sweep: the sweep captured no frames; lengthen it or lower sim.sweep.capture_interval_mm");
  src.description = fmt::format("simulated {} sweep over the {} phantom, {} probe, {} frames", s.sim.sweep.kind,
                                s.sim.phantom, sim->probe().name, src.frames);
  src.grid = sweepGrid(s, *sim);
  const int threads = s.sim.threads;
  src.run = [sim, threads](const FrameSink& sink) {
    sim->run(threads, [&](Frame&& f) { sink(f, sim->imageToReference(f.index), f.timestamp); });
  };
  return src;
}

Source sequenceSource(const Settings& s) {
  if (s.run.sequence.empty() || s.run.plusConfig.empty())
    throw InputError("run.source = \"sequence\" needs run.sequence and run.plus_config");
  auto seq = std::make_shared<PosedSequence>(openPosedSequence(s.run.sequence, s.run.plusConfig));
  Source src;
  src.frames = seq->reader->info().frameCount;
  src.description = fmt::format("{} ({} frames of {}x{})", s.run.sequence, src.frames, seq->reader->info().width,
                                seq->reader->info().height);
  src.grid = s.grid.autoExtent ? chooseGrid(*seq, s.recon, s.grid.spacing, s.grid.marginMm, false) : s.grid.fixedGrid();
  src.run = [seq](const FrameSink& sink) {
    Frame f;
    for (std::uint64_t i = 0; seq->reader->next(f); ++i)
      if (seq->poses[i]) sink(f, *seq->poses[i], f.timestamp);
  };
  return src;
}

std::vector<std::uint8_t> rgb8(const pp::TileImage& im) {
  std::vector<std::uint8_t> px(static_cast<std::size_t>(im.width) * static_cast<std::size_t>(im.height) * 3);
  const float black[3] = {0.0f, 0.0f, 0.0f};
  pp::toRgb8(im, black, px.data());
  return px;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

int runCommand(const RunOptions& o) {
  Settings s;
  ConfigSchema schema;
  registerAll(schema, s);
  loadSettings(schema, o.file, o.overrides);
  const std::string dir = o.outDir.empty() ? s.output.dir : o.outDir;
  makeOutputDir(dir);

  Source src = s.run.source == "sequence" ? sequenceSource(s) : simulatorSource(s);
  host::PipelineSettings ps{s.recon, s.render, s.shading, s.tf, s.cache};
  spdlog::info("run: {}; grid {}x{}x{} of {} mm; {}x{} image, {} composition", src.description, src.grid.dims.x,
               src.grid.dims.y, src.grid.dims.z, src.grid.spacing.x, s.render.width, s.render.height,
               s.render.compositing.front());
  host::SerialPipeline pipe(src.grid, ps, s.grid.memoryLimitBytes());
  spdlog::info("run: ray cache {:.1f} MiB ({} samples, {} format), shade buffer {:.1f} MiB",
               static_cast<double>(pipe.cache().memoryBytes()) / (1 << 20), pipe.cache().sampleCount(),
               pp::sampleFormatName(pipe.cache().format()),
               static_cast<double>(pipe.shadeBuffer().memoryBytes()) / (1 << 20));
  {
    io::AtomicFile settingsFile((fs::path(dir) / "settings.toml").string());
    settingsFile.write(schema.toToml());
    settingsFile.commit();
  }

  const int w = s.render.width, h = s.render.height;
  host::StatsCsv stats((fs::path(dir) / "stats.csv").string(),
                       {"frame", "recon_ms", "shade_ms", "sample_ms", "composite_ms", "total_ms", "fill_in_slices",
                        "dirty_bricks", "dirty_voxels", "shaded_voxels", "dbuffer_rays", "samples", "rays_composited",
                        "blocks_composited"});
  AnimatedGif buildup((fs::path(dir) / "buildup.gif").string(), w, h, s.run.buildupFps);
  std::vector<double> totals, recons, shades, samplings, composites;
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  auto lastLog = start;
  std::uint64_t done = 0;
  src.run([&](const Frame& f, const Mat4& pose, double t) {
    const host::FrameStats st = pipe.insert(f, pose, t);
    stats.row({static_cast<double>(st.index), st.reconMs, st.shadeMs, st.sampleMs, st.compositeMs, st.totalMs(),
               static_cast<double>(st.fillInSlices), static_cast<double>(st.dirtyBricks),
               static_cast<double>(st.dirtyVoxels), static_cast<double>(st.shadedVoxels),
               static_cast<double>(st.dbufferPixels), static_cast<double>(st.samples),
               static_cast<double>(st.raysComposited), static_cast<double>(st.blocksComposited)});
    totals.push_back(st.totalMs());
    recons.push_back(st.reconMs);
    shades.push_back(st.shadeMs);
    samplings.push_back(st.sampleMs);
    composites.push_back(st.compositeMs);
    if (done % static_cast<std::uint64_t>(s.run.buildupEvery) == 0) buildup.add(rgb8(pipe.image()).data());
    ++done;
    const auto now = Clock::now();
    if (now - lastLog > std::chrono::seconds(2)) {
      const double el = std::chrono::duration<double>(now - start).count();
      spdlog::info("run: frame {}/{}, {:.1f} frames/s, {:.0f} s left", done, src.frames, done / el,
                   static_cast<double>(src.frames - std::min(done, src.frames)) * el / done);
      lastLog = now;
    }
  });
  if (done == 0) throw InputError("run: the source gave no frame that can be placed");

  // The end of the sweep: final passes, then what is shown of the final volume.
  pipe.finish();
  buildup.add(rgb8(pipe.image()).data());
  buildup.close();
  std::vector<std::string> wrote = {"buildup.gif"};
  for (const std::string& mode : s.render.compositing) {
    const pp::CompositeMode m = pp::compositeModeFromName(mode);
    const pp::TileImage im = m == pipe.liveMode() ? pipe.image() : pipe.compositeFull(m);
    const std::string name = "final_" + mode + ".png";
    writeRgbPng((fs::path(dir) / name).string(), w, h, rgb8(im).data());
    wrote.push_back(name);
  }
  if (s.run.mpr) {
    const Index3 c = pipe.reconstructor().grid().dims / Index3(2);
    for (const auto& p : host::writeMpr(pipe.reconstructor().output(), c, (fs::path(dir) / "mpr").string()))
      wrote.push_back(fs::path(p).filename().string());
  }
  if (s.run.volume) {
    writeVolume((fs::path(dir) / "volume.mha").string(), pipe.reconstructor().output().as(ScalarType::U8), true);
    wrote.push_back("volume.mha");
  }
  double orbitMs = 0.0;
  if (s.run.orbitFrames > 0) {
    AnimatedGif orbit((fs::path(dir) / "orbit.gif").string(), w, h, s.run.orbitFps);
    const Camera base = pipe.camera();
    std::vector<double> ms;
    for (int i = 0; i < s.run.orbitFrames; ++i) {
      const auto t = Clock::now();
      pipe.setCamera(base.orbited(Vec3(0, 0, 1), 360.0 * i / s.run.orbitFrames));
      ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t).count());
      orbit.add(rgb8(pipe.image()).data());
    }
    orbit.close();
    orbitMs = median(ms);
    wrote.push_back("orbit.gif");
  }
  wrote.push_back("stats.csv");
  wrote.push_back("settings.toml");

  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  std::printf("run: %llu frames through the serial pipeline in %.1f s\n", static_cast<unsigned long long>(done),
              seconds);
  std::printf("  per frame (median): %.1f ms = reconstruct %.1f + shade %.1f + sample %.1f + composite %.1f\n",
              median(totals), median(recons), median(shades), median(samplings), median(composites));
  if (orbitMs > 0.0) std::printf("  full re-render after a view change (median): %.0f ms\n", orbitMs);
  std::printf("wrote to %s\n", fs::absolute(dir).string().c_str());
  for (const auto& n : wrote) std::printf("  %s\n", n.c_str());
  return 0;
}

}  // namespace

void addRunCommand(CLI::App& app, int& exitCode) {
  auto o = std::make_shared<RunOptions>();
  auto* cmd = app.add_subcommand("run", "Stream the simulator or a sequence through every stage and write the images");
  cmd->add_option("CONFIG", o->file, "TOML configuration (optional)");
  cmd->add_option("-o,--output", o->outDir, "Output folder (default: output.dir)");
  cmd->add_option("--set", o->overrides, "Override an option: key=value (repeatable)");
  cmd->add_flag("--serial", o->serial, "Run the single-process pipeline (what runs without mpirun)");
  cmd->callback([o, &exitCode] { exitCode = runCommand(*o); });
}

}  // namespace pp5::app
