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
#include "app/run_setup.hpp"
#include "reconstruction/recon_run.hpp"
#include "app/settings.hpp"
#include "app/source_settings.hpp"
#include "analysis/speckle_run.hpp"
#include "sim/sweep_cache.hpp"
#include "comm/mpi.hpp"
#include "core/error.hpp"
#include "formats/image_io.hpp"
#include "core/io_util.hpp"
#include "formats/volume_io.hpp"
#include "host/acquisition.hpp"
#include "host/capture.hpp"
#include "host/distributed_pipeline.hpp"
#include "host/local_pipeline.hpp"
#include "host/run_loop.hpp"
#include "outputs/outputs.hpp"
#include "pipeline/parallel_settings.hpp"
#include "pipeline/gp_rank.hpp"
#include "pipeline/pp_rank.hpp"
#include "outputs/sinks.hpp"
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
  std::string igtlServe;  // --igtl-serve [ADDR:]PORT
  bool serve = false;
  int expectRanks = 0;
  int gps = -1, pps = -1;
};

using host::FrameSink;
using host::Source;

std::atomic<bool> gInterrupted{false};
extern "C" void onInterrupt(int) { gInterrupted = true; }
int runSerial(const RunOptions& o) {
  Settings s;
  ConfigSchema schema;
  registerAll(schema, s);
  loadSettings(schema, o.file, o.overrides);
  checkSettings(s, !o.outDir.empty());
  warnUnusedSettings(s, schema, true);
  const std::string dir = o.outDir.empty() ? s.output.dir : o.outDir;
  const bool writeSettings = checkSettingsFileTarget(o.overrides, o.file, dir);
  deriveRunKernel(s, schema);
  host::RunFolder folder(dir);
  std::signal(SIGINT, onInterrupt);
  std::signal(SIGTERM, onInterrupt);

  Source src = makeSource(s);
  const Grid grid = src.grid;
  spdlog::info("run: {}; grid {}x{}x{} of {} mm; {}x{} image, {} composition", src.description, grid.dims.x,
               grid.dims.y, grid.dims.z, grid.spacing.x, s.render.width, s.render.height,
               enumName(s.render.compositing.front()));
  host::RunJob job = makeJob(s, std::move(src), grid, dir, &gInterrupted);
  job.census = o.census;
  host::LocalPipeline pipe(job);
  const outputs::SinkList sinks = outputs::makeSinks(job);
  // Everything that could refuse the run has passed: the folder is the run's now.
  folder.start({o.file, o.census});
  if (writeSettings) writeSettingsFile(schema, dir);
  const int status = host::runLoop(pipe, job, outputs::pointers(sinks));
  if (status == 0) folder.finished();
  return status;
}


// ---- the distributed pipeline (under mpirun) --------------------------------


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
    checkSettings(s, !o.outDir.empty());
    if (rank == 0) warnUnusedSettings(s, schema, false);
    if (o.expectRanks > 0 && size != o.expectRanks)
      throw InputError(fmt::format("--expect-ranks {}: the job has {} ranks (was it started by another MPI's "
                                   "launcher?)",
                                   o.expectRanks, size));
    layout = parallel::RankLayout::choose(size, s.parallel.gps, s.parallel.pps);
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
      gm.kernelMm[0] = s.recon.tent.kernelLateralMm;
      gm.kernelMm[1] = s.recon.tent.kernelAxialMm;
      gm.kernelMm[2] = s.recon.tent.kernelElevationMm;
    }
    t.broadcast(gm, 0);
    Grid grid;
    for (int a = 0; a < 3; ++a) {
      grid.dims[a] = gm.dims[a];
      grid.origin[a] = gm.origin[a];
      grid.spacing[a] = gm.spacing[a];
    }
    // Every rank reconstructs, or reaches, with the host's kernel (derived there, or as read by all).
    s.recon.tent.kernelLateralMm = gm.kernelMm[0];
    s.recon.tent.kernelAxialMm = gm.kernelMm[1];
    s.recon.tent.kernelElevationMm = gm.kernelMm[2];
    switch (layout.role(rank)) {
      case parallel::Role::Host: {
        host::RunJob j = makeJob(s, std::move(src), grid, dir, &gInterrupted);
        j.layout = layout;
        j.verify = o.verify;
        spdlog::info("run: {}; grid {}x{}x{} of {} mm; {}x{} image; {} ranks: 1 host, {} GP ({} partition), {} PP "
                     "({} tiles of {} px), compositing on {}",
                     j.source.description, grid.dims.x, grid.dims.y, grid.dims.z, grid.spacing.x, s.render.width,
                     s.render.height, size, layout.gps, enumName(s.parallel.gpPartition), layout.pps,
                     enumName(s.parallel.tileOwner), s.parallel.tileSize, enumName(s.parallel.compositeOn));
        host::DistributedPipeline pipe(t, j);
        const outputs::SinkList sinks = outputs::makeSinks(j);
        folder->start({o.file});  // the settings and the source have passed: the folder is the run's now
        if (writeSettings) writeSettingsFile(schema, dir);
        status = host::runLoop(pipe, j, outputs::pointers(sinks));
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
    if (o.gps >= 0 || o.pps >= 0)
      throw InputError(fmt::format("{}: lays out the ranks of a run under mpirun; this run is one process ({})",
                                   o.gps >= 0 ? "--gps" : "--pps", o.serial ? "--serial" : "not started by mpirun"));
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
  cmd->add_option("--igtl-serve", o->igtlServe,
                  "Serve the run over OpenIGTLink at [ADDR:]PORT (address 127.0.0.1 unless given; sets "
                  "run.igtl_serve): the live volume and the B-mode frames to 3D Slicer and other clients");
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
  host::RunJob job = makeJob(s, host::Source{}, v.grid, s.output.dir, &gInterrupted);
  host::LocalPipeline pipe(v, job);
  const std::unique_ptr<host::Sink> viewer = outputs::makeViewerSink(job);
  host::serveVolume(pipe, job, {viewer.get()});
  return 0;
}

// --source becomes overrides placed before the user's own --set ones.
int runWithSource(RunOptions o, const std::string& record) {
  std::vector<std::string> extra;
  if (!o.source.empty()) extra = sourceOverrides(o.source);
  if (!record.empty()) extra.push_back(fmt::format("run.record=\"{}\"", record));
  if (!o.view.empty()) extra.push_back(fmt::format("view.listen=\"{}\"", o.view));
  if (!o.igtlServe.empty()) extra.push_back(fmt::format("run.igtl_serve=\"{}\"", o.igtlServe));
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
