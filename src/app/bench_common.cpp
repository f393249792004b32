// The command lines of `pp5echo bench`'s children and the MPI ping-pong
// (app/bench_common.hpp).
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

std::vector<std::string> serialArgv(const std::string& exe, const std::string& file,
                                    const std::vector<std::string>& overrides, const sim::SimulatedSweep& seq,
                                    const std::string& dir, const std::string& census) {
  std::vector<std::string> argv = {exe, "run", fs::absolute(file).string(), "--serial", "-o", dir};
  if (!census.empty()) {
    argv.push_back("--census");
    argv.push_back(census);
  }
  std::vector<std::string> sets = {"run.source=\"sequence\"", "run.sequence=" + tomlString(seq.sequencePath),
                                   "run.plus_config=" + tomlString(seq.configPath), "render.threads=1",
                                   "recon.threads=1"};
  sets.insert(sets.end(), overrides.begin(), overrides.end());
  // What one core does per frame: every frame, unpaced (a pace would only add waits, and drops if it fell behind).
  sets.push_back("run.pace_fps=0");
  for (const auto& s : sets) {
    argv.push_back("--set");
    argv.push_back(s);
  }
  return argv;
}

std::vector<std::string> mpirunArgv(const std::string& mpirun, bool tcp, int ranks) {
  std::vector<std::string> argv = {mpirun};
  if (tcp) argv.insert(argv.end(), {"--mca", "pml", "ob1", "--mca", "btl", "tcp,self"});
  argv.insert(argv.end(), {"-n", std::to_string(ranks)});
  return argv;
}

std::vector<std::string> layoutArgv(const std::string& mpirun, const std::string& exe, const std::string& file,
                                    const std::vector<std::string>& overrides, const std::string& plusConfig,
                                    const Layout& l, const std::string& dir, const std::string& sequence,
                                    bool baseline) {
  std::vector<std::string> argv = mpirunArgv(mpirun, l.tcp, l.ranks());
  argv.insert(argv.end(), {exe, "run", fs::absolute(file).string(), "-o", dir, "--expect-ranks",
                           std::to_string(l.ranks())});
  std::vector<std::string> sets = {
      "run.source=\"sequence\"", "run.sequence=" + tomlString(sequence), "run.plus_config=" + tomlString(plusConfig),
      fmt::format("parallel.gps={}", l.gps), fmt::format("parallel.pps={}", l.pps),
      fmt::format("parallel.gp_partition=\"{}\"", l.partition), fmt::format("parallel.tile_owner=\"{}\"", l.owner),
      fmt::format("parallel.tile_size={}", l.tileSize), fmt::format("run.pace_fps={:g}", l.paceFps)};
  sets.insert(sets.end(), overrides.begin(), overrides.end());
  if (baseline) sets.push_back("run.script=[]");  // one frame: no view change
  for (const std::string& set : sets) {
    argv.push_back("--set");
    argv.push_back(set);
  }
  return argv;
}

Bandwidth measureBandwidth(const std::string& mpirun, const std::string& exe, const std::string& dir, bool tcp,
                           const std::atomic<bool>* stop) {
  Bandwidth b;
  const std::string log = (fs::path(dir) / (tcp ? "pingpong_tcp.log" : "pingpong.log")).string();
  std::vector<std::string> argv = mpirunArgv(mpirun, tcp, 2);
  argv.insert(argv.end(), {exe, "bench", "--pingpong"});
  const ChildResult r = runChild(argv, log, 60.0, stop);
  std::ifstream in(log);
  for (std::string l; std::getline(in, l);) {
    std::istringstream ls(l);
    std::string w;
    std::size_t bytes = 0;
    double s = 0.0, bps = 0.0;
    if (ls >> w >> bytes >> s >> bps && w == "pingpong") {
      if (bytes == 8) b.latencyS = s;
      if (bytes == (std::size_t{1} << 20)) {
        b.bytesPerS = bps;
        b.measured = true;
      }
      b.text += fmt::format("{}{} B: {:.2f} us one way, {:.2f} GB/s", b.text.empty() ? "" : "; ", bytes, s * 1e6,
                            bps / 1e9);
    }
  }
  if (r.status != 0 || !b.measured) {
    // Not measured: ../shared/environment.md's figure for this machine class.
    b.bytesPerS = 5e9;
    b.measured = false;
    b.text = fmt::format("ping-pong failed (exit {}; see {}); assumed 5 GB/s", r.status, log);
  }
  return b;
}


}  // namespace pp5::app
