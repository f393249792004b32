// `pp5echo bench CONFIG [-o DIR] [--quick]`: the partitioning benchmark. It
// simulates the configured sweep once into a PLUS sequence (and checks that
// reading it back gives the simulator's frames and poses), then runs the
// distributed pipeline on that sequence in many layouts, each as its own
// `mpirun -n N pp5echo run` child with a timeout, and collects every run's
// summary.json into bench.csv, summary.md and plots (scripts/bench_plots.py).
// A layout that fails is reported with its exit status and the end of its log,
// and the bench goes on.
//
// The figures of a shared two-core machine are wall-clock ones of N ranks on
// 2 cores, so each row also carries every rank's CPU seconds and a cost model:
// per frame, the busiest rank's CPU time plus the busiest rank's bytes over a
// link, which estimates what one rank per core (or per node) would sustain.
#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <tuple>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "app/bench_common.hpp"
#include "app/commands.hpp"
#include "reconstruction/recon_run.hpp"
#include "app/settings.hpp"
#include "sim/sweep_cache.hpp"
#include "comm/mpi.hpp"
#include "core/error.hpp"
#include "core/io_util.hpp"
#include "formats/plus_config.hpp"
#include "formats/sequence_io.hpp"
#include "benchmark/child_process.hpp"
#include "benchmark/cost_model.hpp"
#include "benchmark/layouts.hpp"
#include "benchmark/report.hpp"
#include "sim/simulate.hpp"


namespace pp5::app {

namespace fs = std::filesystem;
using namespace pp5::harness;

namespace {

using Clock = std::chrono::steady_clock;

struct BenchOptions {
  std::string file, outDir;
  std::vector<std::string> overrides;
  bool quick = false;
  bool list = false;
  std::string only;
  double timeoutS = 150.0;
  std::string plotsScript;
  bool pingpong = false;  // hidden: the ping-pong child under mpirun
  bool costModel = false;  // --cost-model
  int repeats = 0;         // --repeat (cost model; 0: 3, or 1 with --quick)
};

std::atomic<bool> gStop{false};
extern "C" void onBenchInterrupt(int) { gStop = true; }

// ---- MPI bandwidth -------------------------------------------------------------

// The hidden `bench --pingpong` child: two ranks bounce messages of a few sizes.
int runPingPong() {
  const comm::MpiSession mpi;
  if (mpi.size() != 2) {
    if (mpi.rank() == 0) std::fprintf(stderr, "bench --pingpong: needs exactly 2 ranks, got %d\n", mpi.size());
    return 1;
  }
  for (const std::size_t bytes : {std::size_t{8}, std::size_t{64} << 10, std::size_t{1} << 20, std::size_t{4} << 20}) {
    const double best = mpi.pingPongSeconds(bytes, bytes < 4096 ? 1000 : 20, 5);
    if (mpi.rank() == 0) std::printf("pingpong %zu %.9f %.6e\n", bytes, best, static_cast<double>(bytes) / best);
  }
  return 0;
}

// ---- the serial reference ------------------------------------------------------------

// `pp5echo run --serial` on the same sequence, one thread: what one core does
// per frame with no messages (the serial path has no scripted view change).
SerialRef runSerialReference(const std::string& exe, const BenchOptions& o, const sim::SimulatedSweep& seq, double timeoutS) {
  SerialRef r;
  const std::string dir = fs::absolute(fs::path(o.outDir) / "layouts" / "serial").string();
  std::error_code ec;
  fs::remove_all(dir, ec);
  makeOutputDir(dir);
  r.log = (fs::path(dir) / "run.log").string();
  r.child = runChild(serialArgv(exe, o.file, o.overrides, seq, dir, ""), r.log, timeoutS, &gStop);
  if (r.child.status != 0) return r;
  r.ok = readSerialStats((fs::path(dir) / "stats.csv").string(), r);
  return r;
}

std::string findPlotsScript(const std::string& given) {
  if (!given.empty()) return given;
  std::vector<fs::path> tries = {fs::current_path() / "scripts/bench_plots.py"};
  std::error_code ec;
  fs::path d = fs::read_symlink("/proc/self/exe", ec).parent_path();
  for (int i = 0; i < 5 && !d.empty(); ++i, d = d.parent_path()) tries.push_back(d / "scripts/bench_plots.py");
  for (const auto& p : tries)
    if (fs::exists(p, ec)) return p.string();
  return {};
}

void makePlots(const BenchOptions& o, const std::string& csv) {
  const std::string script = findPlotsScript(o.plotsScript);
  if (script.empty()) {
    std::printf("bench: note: scripts/bench_plots.py not found (give --plots-script); no plots\n");
    return;
  }
  const std::string py = fs::exists("/usr/bin/python3") ? "/usr/bin/python3" : findInPath("python3");
  if (py.empty() || std::system(fmt::format("'{}' -c 'import matplotlib' >/dev/null 2>&1", py).c_str()) != 0) {
    std::printf("bench: note: matplotlib is missing (apt-get install python3-matplotlib); no plots\n");
    return;
  }
  const std::string log = (fs::path(o.outDir) / "plots.log").string();
  const ChildResult r = runChild({py, script, csv, o.outDir}, log, 120.0, &gStop);
  if (r.status != 0) std::printf("bench: plots failed (exit %d):\n%s", r.status, tail(log, 10).c_str());
  else std::printf("%s", tail(log, 10).c_str());
}

// ---- the bench -----------------------------------------------------------------------

// mpirun from PATH and this program, which the bench's children run.
std::pair<std::string, std::string> mpirunAndSelf() {
  const std::string mpirun = findInPath("mpirun");
  if (mpirun.empty()) throw InputError("bench: mpirun is not on PATH (install openmpi-bin)");
  std::error_code ec;
  const std::string exe = fs::read_symlink("/proc/self/exe", ec).string();
  if (ec) throw InputError("bench: cannot find this program through /proc/self/exe");
  return {mpirun, exe};
}

int runBench(BenchOptions o) {
  if (o.pingpong) return runPingPong();
  if (o.file.empty()) throw InputError("bench: give the workload's configuration, e.g. configs/bench.toml");
  Settings s;
  ConfigSchema schema;
  registerAll(schema, s);
  loadSettings(schema, o.file, o.overrides);
  if (o.outDir.empty()) o.outDir = s.output.dir;

  if (o.costModel) {
    // Named, not a structured binding: clang 14 cannot capture one in a lambda.
  const auto launcher = mpirunAndSelf();
  const auto& mpirun = std::get<0>(launcher);
  const auto& exe = std::get<1>(launcher);
    std::signal(SIGINT, onBenchInterrupt);
    std::signal(SIGTERM, onBenchInterrupt);
    CostModelRun run;
    run.mpirun = mpirun;
    run.exe = exe;
    run.file = o.file;
    run.outDir = o.outDir;
    run.overrides = o.overrides;
    run.timeoutS = o.timeoutS;
    run.stop = &gStop;
    run.quick = o.quick;
    run.repeats = o.repeats > 0 ? o.repeats : (o.quick ? 1 : 3);
    return runCostModel(run);
  }

  std::vector<Layout> all = layouts(o.quick);
  if (!o.only.empty())
    std::erase_if(all, [&](const Layout& l) { return l.name().find(o.only) == std::string::npos; });
  if (o.list) {
    for (const Layout& l : all) std::printf("%s  (%d ranks)\n", l.name().c_str(), l.ranks());
    return 0;
  }
  if (all.empty()) throw InputError(fmt::format("bench: no layout's name contains \"{}\"", o.only));
  // Named, not a structured binding: clang 14 cannot capture one in a lambda.
  const auto launcher = mpirunAndSelf();
  const auto& mpirun = std::get<0>(launcher);
  const auto& exe = std::get<1>(launcher);
  std::error_code ec;

  makeOutputDir(o.outDir);
  std::signal(SIGINT, onBenchInterrupt);
  std::signal(SIGTERM, onBenchInterrupt);
  const auto start = Clock::now();
  auto elapsed = [&] { return std::chrono::duration<double>(Clock::now() - start).count(); };

  std::printf("bench: simulating the sweep once into %s/sequence\n", o.outDir.c_str());
  std::fflush(stdout);
  const sim::SimulatedSweep seq = sim::simulateSweep(s.sim, sweepGridOf(s), (fs::path(o.outDir) / "sequence").string());
  std::printf("bench: %zu frames in %.1f s; read back with identical pixels, poses within %.1e mm\n", seq.frames,
              seq.simulateS, seq.maxPoseError);
  const Bandwidth bw = measureBandwidth(mpirun, exe, o.outDir, false, &gStop);
  std::printf("bench: MPI ping-pong: %s\n", bw.text.c_str());
  std::fflush(stdout);
  const SerialRef serial = runSerialReference(exe, o, seq, o.timeoutS);
  std::printf("bench: serial reference: %s\n", serialText(serial).c_str());
  std::fflush(stdout);

  std::vector<Row> rows;
  std::map<std::string, std::vector<double>> baselines;  // per unpaced layout name: CPU s per rank
  const std::string csv = (fs::path(o.outDir) / "bench.csv").string();
  const std::string md = (fs::path(o.outDir) / "summary.md").string();
  double rankSeconds = 0.0;  // wall seconds per rank-count unit, for the estimate
  std::size_t totalRanks = 0;
  for (const Layout& l : all) totalRanks += static_cast<std::size_t>(l.ranks());
  std::size_t ranksDone = 0;
  for (std::size_t i = 0; i < all.size() && !gStop; ++i) {
    const Layout& l = all[i];
    Row r;
    r.layout = l;
    r.dir = fs::absolute(fs::path(o.outDir) / "layouts" / l.name()).string();
    fs::remove_all(r.dir, ec);
    makeOutputDir(r.dir);
    r.log = (fs::path(r.dir) / "run.log").string();
    auto argvFor = [&](const std::string& dir, const std::string& sequence, bool baseline) {
      return layoutArgv(mpirun, exe, o.file, o.overrides, seq.configPath, l, dir, sequence, baseline);
    };
    const double left = ranksDone ? rankSeconds / static_cast<double>(ranksDone) *
                                        static_cast<double>(totalRanks - ranksDone)
                                  : 0.0;
    std::printf("bench: [%zu/%zu] %s: %d ranks (1 host, %d GP, %d PP)  elapsed %s%s\n", i + 1, all.size(),
                l.name().c_str(), l.ranks(), l.gps, l.pps, clockText(elapsed()).c_str(),
                ranksDone ? fmt::format(", about {} left", clockText(left)).c_str() : "");
    std::fflush(stdout);
    // The baseline: the same layout on the sweep's first frame alone, whose CPU
    // time (start-up, one frame, the final pass over a nearly empty grid) the
    // steady model takes off; once per layout, paced or not.
    Layout twin = l;
    twin.paceFps = 0.0;
    twin.repeat = 1;
    if (const auto it = baselines.find(twin.name()); it != baselines.end()) {
      r.baseCpu = it->second;
      r.baseOk = true;
    } else {
      const std::string bdir = (fs::path(r.dir) / "baseline").string();
      makeOutputDir(bdir);
      const std::string blog = (fs::path(bdir) / "run.log").string();
      r.baseChild = runChild(argvFor(bdir, seq.firstPath, true), blog, o.timeoutS, &gStop);
      rankSeconds += r.baseChild.wallS;
      const std::string bsum = (fs::path(bdir) / "summary.json").string();
      if (r.baseChild.status == 0 && fs::exists(bsum)) {
        try {
          std::ifstream in(bsum);
          r.baseCpu = perRankCpu(json::parse(in));
          r.baseOk = r.baseCpu.size() == static_cast<std::size_t>(l.ranks());
        } catch (const std::exception&) {
        }
      }
      if (r.baseOk) baselines[twin.name()] = r.baseCpu;
      if (!r.baseOk)
        std::printf("bench:   baseline run failed (exit %d); the log %s ends:\n%s", r.baseChild.status, blog.c_str(),
                    tail(blog, 10).c_str());
      if (gStop) break;
    }
    const std::vector<std::string> argv = argvFor(r.dir, seq.sequencePath, false);
    r.loadBefore = loadAverage();
    r.child = runChild(argv, r.log, o.timeoutS, &gStop);
    r.loadAfter = loadAverage();
    rankSeconds += r.child.wallS;
    ranksDone += static_cast<std::size_t>(l.ranks());
    const std::string summaryPath = (fs::path(r.dir) / "summary.json").string();
    if (r.child.status == 0 && fs::exists(summaryPath)) {
      try {
        std::ifstream in(summaryPath);
        r.summary = json::parse(in);
        derive(r, seq.frames, bw);
        r.ok = true;
      } catch (const std::exception& e) {
        r.error = fmt::format("{}: {}", summaryPath, e.what());
      }
    }
    if (!r.ok) {
      r.logTail = tail(r.log, 15);
      std::printf("bench:   FAILED (%s) after %.1f s; the log %s ends:\n%s", 
                  r.child.interrupted ? "interrupted"
                  : r.child.timedOut  ? fmt::format("timed out after {:.0f} s", o.timeoutS).c_str()
                  : r.error.empty()   ? fmt::format("exit status {}", r.child.status).c_str()
                                      : r.error.c_str(),
                  r.child.wallS, r.log.c_str(), r.logTail.c_str());
    } else {
      std::printf("bench:   %.1f s: %.1f frames/s in, %llu dropped, latency median %.0f ms, p95 %.0f ms; CPU s sum "
                  "%.1f, max %.1f (%s)%s\n",
                  r.child.wallS, num(r.summary, "frames_per_s_in"), static_cast<unsigned long long>(r.drops),
                  num(r.summary, "latency_ms_median"), num(r.summary, "latency_ms_p95"), r.cpuSum, r.cpuMax,
                  r.cpuMaxRank.c_str(),
                  l.paceFps == 0.0 ? fmt::format("; model (10 GbE) {:.0f} frames/s, steady {}", 1e3 / r.modelEthMs,
                                                 r.baseOk ? fmt::format("{:.0f}", 1e3 / r.steadyEthMs) : "-")
                                         .c_str()
                                   : "");
    }
    std::fflush(stdout);
    rows.push_back(std::move(r));
    writeCsv(csv, rows);  // as it goes, so an interrupted bench keeps what it measured
  }
  writeCsv(csv, rows);
  ReportContext context;
  context.command = "pp5echo bench " + o.file + " -o " + o.outDir + (o.quick ? " --quick" : "");
  for (const auto& set : o.overrides) context.command += " --set " + set;
  context.sequenceFrames = seq.frames;
  context.sequencePath = seq.sequencePath;
  context.maxPoseError = seq.maxPoseError;
  context.bandwidth = bw;
  context.serial = serial;
  context.benchS = elapsed();
  writeMarkdown(md, rows, context);
  if (gStop) std::printf("bench: interrupted; no plots (run scripts/bench_plots.py on bench.csv)\n");
  else makePlots(o, csv);
  int failed = 0;
  for (const Row& r : rows) failed += r.ok ? 0 : 1;
  std::printf("bench: %zu layouts (%d failed) in %s\n", rows.size(), failed, clockText(elapsed()).c_str());
  for (const Row& r : rows)
    if (r.layout.target && r.layout.paceFps > 0.0) std::printf("  target %s: %s\n", r.layout.name().c_str(), verdict(r).c_str());
  std::printf("wrote to %s\n  bench.csv\n  summary.md\n  layouts/<name>/ (each run's outputs and run.log)\n",
              fs::absolute(o.outDir).string().c_str());
  if (gStop) {
    std::printf("bench: interrupted\n");
    return 130;
  }
  // Failed layouts are reported, not fatal: the bench's job is the table. A
  // bench where nothing ran is an error.
  return failed == static_cast<int>(rows.size()) ? 1 : 0;
}

}  // namespace

void addBenchCommand(CLI::App& app, int& exitCode) {
  auto o = std::make_shared<BenchOptions>();
  auto* cmd = app.add_subcommand(
      "bench", "Partitioning benchmark: run the distributed pipeline in many layouts (mpirun children) and tabulate");
  cmd->add_option("CONFIG", o->file, "The workload's TOML configuration (configs/bench.toml)");
  cmd->add_option("-o,--output", o->outDir, "Output folder (default: output.dir)");
  cmd->add_option("--set", o->overrides, "Override an option for the sweep and every run: key=value (repeatable)");
  cmd->add_flag("--quick", o->quick, "A small subset of layouts (a smoke test)");
  cmd->add_option("--only", o->only, "Run only the layouts whose name contains this text");
  cmd->add_flag("--list", o->list, "Print the layouts and exit");
  cmd->add_option("--timeout", o->timeoutS, "Seconds a layout may run before it is stopped (default 150)");
  cmd->add_option("--plots-script", o->plotsScript, "scripts/bench_plots.py (default: found near here)");
  cmd->add_flag("--cost-model", o->costModel,
                "Fit the cost model on some layouts, predict others, run them and report the error (cost_model.md)");
  cmd->add_option("--repeat", o->repeats, "Cost model: runs of each layout, whose median it reports (default 3; 1 with --quick)")
      ->check(CLI::Range(1, 20));
  cmd->add_flag("--pingpong", o->pingpong, "Internal: the MPI ping-pong the bench runs under mpirun")->group("");
  cmd->callback([o, &exitCode] { exitCode = runBench(*o); });
}

}  // namespace pp5::app
