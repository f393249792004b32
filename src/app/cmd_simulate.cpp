// `pp5echo simulate [CONFIG] -o DIR [--set key=value ...]`: a simulated tracked
// sweep over a phantom, written as PLUS data with its ground truth:
//   <phantom>_sweep.igs.mha   the frames with their poses (compressed PLUS sequence)
//   <phantom>_config.xml      PLUS config: ImageToProbe and VolumeReconstruction
//   <phantom>_truth.mha       ground-truth echogenicity on the [grid]
//   frame_NNNN.png            a few frames as images (output.preview_frames)
//   settings.toml             every setting the run used
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "app/commands.hpp"
#include "app/settings.hpp"
#include "core/error.hpp"
#include "formats/image_io.hpp"
#include "core/io_util.hpp"
#include "formats/plus_config.hpp"
#include "formats/sequence_io.hpp"
#include "formats/volume_io.hpp"
#include "sim/simulate.hpp"

namespace fs = std::filesystem;

namespace pp5::app {

namespace {

struct SimulateOptions {
  std::string file;
  std::string outDir;
  std::vector<std::string> overrides;
};

std::shared_ptr<spdlog::logger> logger() {
  auto log = spdlog::get("simulate");
  return log ? log : spdlog::stderr_color_mt("simulate");
}

// `count` frame numbers spread evenly over 0..n-1 (first and last included).
std::set<std::size_t> previewIndices(std::size_t n, int count) {
  std::set<std::size_t> out;
  if (n == 0 || count <= 0) return out;
  if (count == 1) {
    out.insert(n / 2);
    return out;
  }
  for (int k = 0; k < count; ++k)
    out.insert(static_cast<std::size_t>(std::llround(static_cast<double>(k) * static_cast<double>(n - 1) / (count - 1))));
  return out;
}

void writeTextAtomically(const std::string& path, const std::string& text) {
  io::AtomicFile out(path);
  out.write(text);
  out.commit();
}

PlusVolumeReconstruction reconstructionElement(const Grid& g) {
  PlusVolumeReconstruction r;
  r.imageCoordinateFrame = "Image";
  r.referenceCoordinateFrame = "Reference";
  r.outputSpacing = g.spacing;
  r.outputOrigin = g.origin;
  r.outputExtent = std::array<int, 6>{0, static_cast<int>(g.dims.x - 1), 0, static_cast<int>(g.dims.y - 1), 0,
                                      static_cast<int>(g.dims.z - 1)};
  r.interpolation = PlusInterpolation::Linear;
  r.compounding = PlusCompounding::Mean;
  return r;
}

int runSimulate(const SimulateOptions& opts) {
  Settings s;
  ConfigSchema schema;
  registerAll(schema, s);
  loadSettings(schema, opts.file, opts.overrides);
  const std::string dir = opts.outDir.empty() ? s.output.dir : opts.outDir;
  auto log = logger();

  makeOutputDir(dir);

  const sim::SweepSimulator sim(s.sim);
  const std::size_t n = sim.frameCount();
  if (n == 0) throw InputError("sim.sweep: the sweep captured no frames; lengthen it or lower sim.sweep.capture_interval_mm");

  // Refuse a truth grid that cannot fit before spending time on the frames.
  const Grid grid = sweepGrid(s, sim);
  const ScalarType truthType = s.sim.truthType == sim::TruthType::Uint8 ? ScalarType::U8 : ScalarType::F32;
  checkGridFits(grid, 8 + static_cast<std::uint64_t>(scalarBytes(truthType)), "truth volume ([grid])",
                s.grid.memoryLimitBytes());

  const std::string stem(enumName(s.sim.phantom));
  const std::string seqPath = (fs::path(dir) / (stem + "_sweep.igs.mha")).string();
  const std::string cfgPath = (fs::path(dir) / (stem + "_config.xml")).string();
  const std::string truthPath = (fs::path(dir) / (stem + "_truth.mha")).string();
  const std::string expectedPath = (fs::path(dir) / (stem + "_expected.mha")).string();
  const std::string settingsPath = (fs::path(dir) / "settings.toml").string();

  log->info("simulate: {} phantom, {} probe ({}x{} px, {} x {} mm), {} sweep: {} frames", stem, sim.probe().name,
            sim.probe().width, sim.probe().height, sim.probe().widthMm, sim.probe().depthMm, enumName(s.sim.sweep.kind), n);

  SequenceWriteOptions wo;
  wo.compress = true;
  wo.fields = {{"UltrasoundImageType", "BRIGHTNESS"}};
  auto writer = SequenceWriter::create(seqPath, wo);
  const auto previews = previewIndices(n, s.output.previewFrames);
  std::vector<std::string> pngs;
  const std::size_t logEvery = std::max<std::size_t>(1, n / 10);
  sim.run(
      s.sim.threads,
      [&](Frame&& f) {
        if (previews.count(f.index)) {
          const std::string png = (fs::path(dir) / fmt::format("frame_{:04d}.png", f.index)).string();
          writeGrayPng(png, f.width, f.height, f.u8());
          pngs.push_back(png);
        }
        writer->write(f);
      },
      [&](std::size_t done, std::size_t total) {
        if (done % logEvery == 0 || done == total) log->info("simulate: frames {}/{}", done, total);
      });
  writer->close();

  const std::string description =
      fmt::format("pp5echo simulate: {} phantom, {} probe, {} sweep, seed {}", stem, sim.probe().name,
                  enumName(s.sim.sweep.kind), s.sim.seed);
  // ReferenceToTracker is fixed, so the configuration holds it too: a live
  // source (the board, OpenIGTLink) that sends only ProbeToTracker is then
  // placed by this file alone.
  writePlusConfig(cfgPath, {{"Image", "Probe", sim.imageToProbe()}, {"Reference", "Tracker", sim.referenceToTracker()}}, reconstructionElement(grid), description);

  log->info("simulate: truth volume {}x{}x{} voxels", grid.dims.x, grid.dims.y, grid.dims.z);
  const Volume truth = sim::truthVolume(sim.phantom(), sim.bmode(), grid, truthType, s.sim.threads,
                                        s.grid.memoryLimitBytes());
  writeVolume(truthPath, truth, true);
  {
    // A grid that misses the phantom (grid.auto_extent = false, an origin far
    // away) samples one value everywhere: said, not left to be found.
    const std::size_t voxels = static_cast<std::size_t>(grid.voxelCount());
    const double first = truth.value(0);
    std::size_t i = 1;
    while (i < voxels && truth.value(i) == first) ++i;
    if (i == voxels)
      log->warn("simulate: the truth volume is {} everywhere: the grid (origin {} {} {} mm, {}x{}x{} voxels of {} mm) "
                "does not reach the phantom's structures; check grid.origin and grid.dims, or set grid.auto_extent = "
                "true",
                first, grid.origin.x, grid.origin.y, grid.origin.z, grid.dims.x, grid.dims.y, grid.dims.z,
                grid.spacing.x);
  }
  // The expected image, for a probe held as at the middle of the sweep.
  const Mat4 probePose = sim.trueImageToReference(n / 2) * affineInverse(sim.imageToProbe());
  bool wroteExpected = false;
  try {
    log->info("simulate: expected-image volume");
    writeVolume(expectedPath,
                sim::expectedImageVolume(sim.phantom(), sim.bmode(), grid, probePose, truthType, s.sim.threads,
                                         s.grid.memoryLimitBytes()),
                true);
    wroteExpected = true;
  } catch (const InputError& e) {
    log->warn("simulate: no expected-image volume: {}", e.what());
  }
  writeTextAtomically(settingsPath, schema.toToml());

  std::printf("simulate: wrote to %s\n", fs::absolute(dir).string().c_str());
  std::printf("  %s  (%zu frames, %dx%d, %.1f s of sweep)\n", fs::path(seqPath).filename().string().c_str(), n,
              sim.probe().width, sim.probe().height, sim.sweep().duration);
  std::printf("  %s  (ImageToProbe, VolumeReconstruction)\n", fs::path(cfgPath).filename().string().c_str());
  std::printf("  %s  (%lldx%lldx%lld %s, spacing %g %g %g mm)\n", fs::path(truthPath).filename().string().c_str(),
              static_cast<long long>(grid.dims.x), static_cast<long long>(grid.dims.y),
              static_cast<long long>(grid.dims.z), scalarName(truthType), grid.spacing.x, grid.spacing.y,
              grid.spacing.z);
  if (wroteExpected)
    std::printf("  %s  (the expected image: what a perfect reconstruction shows in the ideal medium)\n",
                fs::path(expectedPath).filename().string().c_str());
  for (const auto& p : pngs) std::printf("  %s\n", fs::path(p).filename().string().c_str());
  std::printf("  settings.toml\n");
  return 0;
}

}  // namespace

void addSimulateCommand(CLI::App& app, int& exitCode) {
  auto opts = std::make_shared<SimulateOptions>();
  auto* cmd = app.add_subcommand(
      "simulate", "Simulate a tracked sweep over a phantom: PLUS sequence and config, truth volume, preview PNGs");
  cmd->add_option("CONFIG", opts->file, "TOML configuration (optional)");
  cmd->add_option("-o,--output", opts->outDir, "Output folder (default: output.dir)");
  cmd->add_option("--set", opts->overrides, "Override an option: key=value (repeatable)");
  cmd->callback([opts, &exitCode] { exitCode = runSimulate(*opts); });
}

}  // namespace pp5::app
