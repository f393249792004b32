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
#include <thread>
#include <vector>

#include <fcntl.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "app/commands.hpp"
#include "app/recon_run.hpp"
#include "app/settings.hpp"
#include "comm/mpi.hpp"
#include "core/error.hpp"
#include "core/io_util.hpp"
#include "core/plus_config.hpp"
#include "core/sequence_io.hpp"
#include "sim/simulate.hpp"

extern char** environ;

namespace pp5::app {

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

// A cluster link, for the cost model's second estimate (stated in summary.md).
constexpr double kEthernetBytesPerS = 10e9 / 8.0;  // 10 Gb/s Ethernet
// The pipeline's stages, in the order summary.json lists them.
const std::vector<std::string> kStages = {"receive", "reconstruct", "shade", "sample", "send", "wait", "composite"};
// The GP's stages whose CPU time bench.csv estimates.
const std::vector<std::string> kGpStages = {"reconstruct", "shade", "sample", "send"};

struct BenchOptions {
  std::string file, outDir;
  std::vector<std::string> overrides;
  bool quick = false;
  bool list = false;
  std::string only;
  double timeoutS = 150.0;
  std::string plotsScript;
  bool pingpong = false;  // hidden: the ping-pong child under mpirun
};

std::atomic<bool> gStop{false};
extern "C" void onBenchInterrupt(int) { gStop = true; }

// ---- layouts -----------------------------------------------------------------

struct Layout {
  int gps = 2, pps = 1;
  std::string partition = "slab";    // parallel.gp_partition
  std::string owner = "contiguous";  // parallel.tile_owner
  int tileSize = 128;                // parallel.tile_size
  double paceFps = 0.0;              // run.pace_fps
  bool target = false;               // the 1 host + 2 GP + 1 PP layout
  int repeat = 1;                    // the paced target runs at the start, middle and end

  int ranks() const { return 1 + gps + pps; }
  std::string name() const {
    std::string n = fmt::format("g{}p{}_{}_{}_t{}", gps, pps, partition, owner == "contiguous" ? "contig" : "inter",
                                tileSize);
    if (paceFps > 0.0) n += fmt::format("_paced{:g}", paceFps);
    if (repeat > 1) n += fmt::format("_r{}", repeat);
    return n;
  }
};

Layout make(int g, int p, const std::string& part, const std::string& owner = "contiguous", int tile = 128,
            double pace = 0.0) {
  Layout l;
  l.gps = g;
  l.pps = p;
  l.partition = part;
  l.owner = owner;
  l.tileSize = tile;
  l.paceFps = pace;
  l.target = g == 2 && p == 1 && owner == "contiguous" && tile == 128;
  return l;
}

// The target first, then G and P sweeps with odd counts, tile ownership and
// tile size. The paced target, which the figures judge, runs three
// times (start, middle, end), since what else the machine runs moves it.
std::vector<Layout> layouts(bool quick) {
  std::vector<Layout> v;
  auto paced = [&](int repeat) {
    for (const char* part : {"slab", "tile"}) {
      v.push_back(make(2, 1, part, "contiguous", 128, 30.0));
      v.back().repeat = repeat;
    }
  };
  for (const char* part : {"slab", "tile"}) v.push_back(make(2, 1, part));
  paced(1);
  if (quick) return {v[0], v[3]};
  for (int g : {1, 3, 5})
    for (const char* part : {"slab", "tile"}) v.push_back(make(g, 1, part));
  paced(2);
  for (int p : {2, 3})
    for (const char* part : {"slab", "tile"}) v.push_back(make(2, p, part));
  for (const char* part : {"slab", "tile"}) v.push_back(make(2, 2, part, "interleaved"));
  v.push_back(make(3, 1, "tile", "interleaved"));
  for (int tile : {64, 256})
    for (const char* part : {"slab", "tile"}) v.push_back(make(2, 2, part, "contiguous", tile));
  paced(3);
  return v;
}

// ---- child processes ---------------------------------------------------------

struct ChildResult {
  int status = -1;        // exit status; 128 + signal when killed; -1 when it could not start
  bool timedOut = false;
  bool interrupted = false;
  double wallS = 0.0;
  double cpuS = 0.0;      // the whole job: mpirun and every rank it reaped
};

std::string findInPath(const std::string& name) {
  const char* path = std::getenv("PATH");
  if (!path) return {};
  std::stringstream ss(path);
  std::string d;
  while (std::getline(ss, d, ':')) {
    if (d.empty()) continue;
    const fs::path p = fs::path(d) / name;
    if (::access(p.c_str(), X_OK) == 0) return p.string();
  }
  return {};
}

// Runs argv in its own process group with Open MPI's root and oversubscribe
// settings, stdout and stderr into `logPath`, stdin from /dev/null. After
// `timeoutS` (or on Ctrl-C) the group gets SIGTERM, then SIGKILL.
ChildResult runChild(const std::vector<std::string>& argv, const std::string& logPath, double timeoutS) {
  ChildResult r;
  std::vector<std::string> env;
  for (char** e = environ; *e; ++e) {
    const std::string s(*e);
    if (s.rfind("OMPI_ALLOW_RUN_AS_ROOT", 0) == 0 || s.rfind("OMPI_MCA_rmaps_base_oversubscribe=", 0) == 0) continue;
    env.push_back(s);
  }
  for (const char* s : {"OMPI_ALLOW_RUN_AS_ROOT=1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1",
                        "OMPI_MCA_rmaps_base_oversubscribe=1"})
    env.emplace_back(s);
  std::vector<char*> envp, args;
  for (auto& s : env) envp.push_back(s.data());
  envp.push_back(nullptr);
  std::vector<std::string> argCopy = argv;
  for (auto& s : argCopy) args.push_back(s.data());
  args.push_back(nullptr);

  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&fa, 1, logPath.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&fa, 1, 2);
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETPGROUP);
  posix_spawnattr_setpgroup(&attr, 0);
  pid_t pid = 0;
  const auto t0 = Clock::now();
  const int rc = posix_spawn(&pid, args[0], &fa, &attr, args.data(), envp.data());
  posix_spawn_file_actions_destroy(&fa);
  posix_spawnattr_destroy(&attr);
  if (rc != 0) {
    std::ofstream(logPath, std::ios::app) << fmt::format("bench: cannot start {}: {}\n", argv[0], std::strerror(rc));
    return r;
  }
  int sent = 0;  // 0: none, 1: SIGTERM, 2: SIGKILL
  Clock::time_point termAt{};
  for (;;) {
    int st = 0;
    rusage ru{};
    const pid_t w = ::wait4(pid, &st, WNOHANG, &ru);
    if (w == pid) {
      r.wallS = std::chrono::duration<double>(Clock::now() - t0).count();
      r.cpuS = static_cast<double>(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
               1e-6 * static_cast<double>(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec);
      r.status = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + (WIFSIGNALED(st) ? WTERMSIG(st) : 0);
      break;
    }
    if (w < 0 && errno != EINTR) {
      r.status = -1;
      break;
    }
    const double el = std::chrono::duration<double>(Clock::now() - t0).count();
    if (sent == 0 && (el > timeoutS || gStop)) {
      r.timedOut = !gStop;
      r.interrupted = gStop;
      ::kill(-pid, SIGTERM);
      termAt = Clock::now();
      sent = 1;
    } else if (sent == 1 && Clock::now() - termAt > std::chrono::seconds(10)) {
      ::kill(-pid, SIGKILL);
      sent = 2;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return r;
}

std::string tail(const std::string& path, int lines) {
  std::ifstream in(path);
  std::vector<std::string> all;
  for (std::string l; std::getline(in, l);) all.push_back(l);
  std::string out;
  for (std::size_t i = all.size() > static_cast<std::size_t>(lines) ? all.size() - lines : 0; i < all.size(); ++i)
    out += all[i] + "\n";
  return out;
}

double loadAverage() {
  std::ifstream in("/proc/loadavg");
  double l = 0.0;
  in >> l;
  return l;
}

std::string tomlString(const std::string& s) {
  std::string o = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') o += '\\';
    o += c;
  }
  return o + "\"";
}

std::string clockText(double s) {
  const long t = std::lround(std::max(0.0, s));
  return fmt::format("{}:{:02d}", t / 60, t % 60);
}

// ---- the sweep, simulated once --------------------------------------------------

struct Sequence {
  std::string sequencePath, configPath;
  std::string firstPath;  // the sweep's first frame alone: the baseline runs' input
  std::size_t frames = 0;
  double maxPoseError = 0.0;  // mm, largest |element| of the pose difference
  double simulateS = 0.0;
};

PlusVolumeReconstruction reconstructionElement(const Grid& g) {
  PlusVolumeReconstruction r;
  r.outputSpacing = g.spacing;
  r.outputOrigin = g.origin;
  r.outputExtent = std::array<int, 6>{0, static_cast<int>(g.dims.x - 1), 0, static_cast<int>(g.dims.y - 1), 0,
                                      static_cast<int>(g.dims.z - 1)};
  r.interpolation = PlusInterpolation::Linear;
  return r;
}

// What `pp5echo simulate` writes (the sequence and its device-set XML with
// ImageToProbe), without the truth volumes; uncompressed, so that a layout's
// host pays only for reading. Then reads it back as `run.source = "sequence"`
// does and requires the simulator's pixels, indices, times and poses.
Sequence simulateSequence(const Settings& s, const std::string& dir) {
  const auto t0 = Clock::now();
  const sim::SweepSimulator sim(s.sim);
  const std::size_t n = sim.frameCount();
  if (n == 0) throw InputError("sim.sweep: the sweep captured no frames; lengthen it or lower sim.sweep.capture_interval_mm");
  makeOutputDir(dir);
  Sequence out;
  out.sequencePath = fs::absolute(fs::path(dir) / (s.sim.phantom + "_sweep.igs.mha")).string();
  out.configPath = fs::absolute(fs::path(dir) / (s.sim.phantom + "_config.xml")).string();
  out.firstPath = fs::absolute(fs::path(dir) / (s.sim.phantom + "_first_frame.igs.mha")).string();
  out.frames = n;
  struct Expected {
    std::uint64_t index;
    double time;
    std::vector<std::uint8_t> pixels;
    Mat4 pose;
  };
  std::vector<Expected> want;
  SequenceWriteOptions wo;
  wo.compress = false;
  wo.fields = {{"UltrasoundImageType", "BRIGHTNESS"}};
  auto writer = SequenceWriter::create(out.sequencePath, wo);
  auto first = SequenceWriter::create(out.firstPath, wo);
  sim.run(s.sim.threads, [&](Frame&& f) {
    want.push_back({f.index, f.timestamp, f.pixels, sim.imageToReference(f.index)});
    if (want.size() == 1) first->write(f);
    writer->write(f);
  });
  writer->close();
  first->close();
  writePlusConfig(out.configPath, {{"Image", "Probe", sim.imageToProbe()}}, reconstructionElement(sweepGrid(s, sim)),
                  fmt::format("pp5echo bench: {} phantom, {} probe, {} sweep, seed {}", s.sim.phantom,
                              sim.probe().name, s.sim.sweep.kind, s.sim.seed));

  PosedSequence seq = openPosedSequence(out.sequencePath, out.configPath);
  if (seq.poses.size() != n)
    throw InvariantError(fmt::format("{}: {} frames read back, {} simulated", out.sequencePath, seq.poses.size(), n));
  Frame f;
  for (std::size_t i = 0; i < n; ++i) {
    if (!seq.reader->next(f)) throw InvariantError(fmt::format("{}: frame {} missing", out.sequencePath, i));
    if (!seq.poses[i]) throw InvariantError(fmt::format("{}: frame {} cannot be placed", out.sequencePath, i));
    if (f.pixels != want[i].pixels || f.index != want[i].index || f.timestamp != want[i].time)
      throw InvariantError(fmt::format("{}: frame {} read back differs from the simulator's (pixels, index or time)",
                                       out.sequencePath, i));
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r)
        out.maxPoseError = std::max(out.maxPoseError, std::abs((*seq.poses[i])[c][r] - want[i].pose[c][r]));
  }
  if (!(out.maxPoseError < 1e-6))
    throw InvariantError(fmt::format("{}: the sequence's ImageToReference differs from the simulator's by {} (mm)",
                                     out.sequencePath, out.maxPoseError));
  out.simulateS = std::chrono::duration<double>(Clock::now() - t0).count();
  return out;
}

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

struct Bandwidth {
  double bytesPerS = 0.0;   // 1 MiB messages
  double latencyS = 0.0;    // 8-byte messages, one way
  bool measured = false;
  std::string text;
};

Bandwidth measureBandwidth(const std::string& mpirun, const std::string& exe, const std::string& dir) {
  Bandwidth b;
  const std::string log = (fs::path(dir) / "pingpong.log").string();
  const ChildResult r = runChild({mpirun, "-n", "2", exe, "bench", "--pingpong"}, log, 60.0);
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
    b.text = fmt::format("ping-pong failed (exit {}; see {}); assumed 5 GB/s shared memory", r.status, log);
  }
  return b;
}

// ---- one layout ------------------------------------------------------------------

struct Row {
  Layout layout;
  ChildResult child, baseChild;
  bool baseOk = false;
  std::vector<double> baseCpu;  // per rank: CPU seconds of the same layout on the first frame alone
  std::string dir, log, error, logTail;
  bool ok = false;
  json summary;
  double loadBefore = 0.0, loadAfter = 0.0;
  // derived
  std::uint64_t frames = 0, drops = 0;
  double cpuSum = 0.0, cpuMax = 0.0, hostCpu = 0.0, gpCpuMax = 0.0, ppCpuMax = 0.0;
  std::string cpuMaxRank;
  double maxRankBytesPerFrame = 0.0;
  double modelCpuMs = 0.0, modelShmMs = 0.0, modelEthMs = 0.0;
  // The same with each rank's baseline CPU taken off: what the frames cost,
  // without start-up (MPI, allocation, the empty grid's shading).
  double steadyCpuMs = 0.0, steadyShmMs = 0.0, steadyEthMs = 0.0, baseCpuMax = 0.0;
  double gpCpuImbalance = 0.0;
  // Per frame, less start-up: the busiest GP, every GP, every rank (ms).
  double gpSteadyMaxMs = 0.0, gpSteadySumMs = 0.0, allSteadySumMs = 0.0;
  std::vector<double> roleImbalance;  // per stage, over the ranks of the role that does it
  // CPU ms per frame by stage, estimated: a rank's wall ms in the stage times
  // its CPU over its busy wall time (every stage but wait), start-up taken
  // off. On a shared machine a rank's wall time in a stage is its CPU time
  // stretched by the cores it did not get, about evenly over the run.
  std::vector<double> gpStageCpuMax, gpStageCpuSum;  // per kGpStages
  double ppCompositeCpuMax = 0.0;
  // From stats.csv, the same estimate split by update: the busiest GP's CPU ms
  // per frame update, and per control update (the view change, the final
  // pass: a full re-shade and re-sample). The incremental model uses the
  // first: what a sweep costs between view changes.
  double gpFrameCpuMs = 0.0, gpControlCpuMs = 0.0, incrementalCpuMs = 0.0, incrementalEthMs = 0.0;
  bool split = false;
};

std::uint64_t droppedFromLog(const std::string& path) {
  std::ifstream in(path);
  for (std::string l; std::getline(in, l);) {
    const auto p = l.find("dropped ");
    if (p != std::string::npos && l.find(" frames (live source behind") != std::string::npos)
      return std::strtoull(l.c_str() + p + 8, nullptr, 10);
  }
  return 0;
}

// stats.csv has a row per GP update. A control update (view change, final
// pass) repeats the frame number of the frame before it, so per GP the second
// row of a frame is a control. Returns the busiest GP's estimated CPU ms over
// all its frame updates, and the largest mean CPU ms per control update.
std::optional<std::pair<double, double>> splitGpUpdates(const std::string& path,
                                                        const std::map<int, double>& cpuPerWall) {
  std::ifstream in(path);
  std::string line;
  if (!std::getline(in, line)) return std::nullopt;
  std::vector<std::string> cols;
  {
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) cols.push_back(c);
  }
  auto col = [&](const std::string& n) {
    return static_cast<std::size_t>(std::find(cols.begin(), cols.end(), n) - cols.begin());
  };
  const std::size_t iFrame = col("frame"), iRank = col("rank"), iRole = col("role");
  std::vector<std::size_t> busy;
  for (const auto& st : kStages)
    if (st != "wait") busy.push_back(col(st + "_ms"));
  for (std::size_t i : busy)
    if (i >= cols.size()) return std::nullopt;
  struct Acc {
    std::set<long> seen;
    double frameMs = 0.0, controlMs = 0.0;
    int controls = 0;
  };
  std::map<int, Acc> gps;
  while (std::getline(in, line)) {
    std::vector<double> v;
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) v.push_back(std::strtod(c.c_str(), nullptr));
    if (v.size() != cols.size() || v[iRole] != 1.0) continue;  // GP rows only (Role::Gp)
    Acc& a = gps[static_cast<int>(v[iRank])];
    double ms = 0.0;
    for (std::size_t i : busy) ms += v[i];
    if (a.seen.insert(static_cast<long>(v[iFrame])).second) {
      a.frameMs += ms;
    } else {
      a.controlMs += ms;
      ++a.controls;
    }
  }
  if (gps.empty()) return std::nullopt;
  double frameMax = 0.0, controlMax = 0.0;
  for (const auto& [rank, a] : gps) {
    const auto it = cpuPerWall.find(rank);
    const double k = it == cpuPerWall.end() ? 0.0 : it->second;
    frameMax = std::max(frameMax, a.frameMs * k);
    if (a.controls) controlMax = std::max(controlMax, a.controlMs * k / a.controls);
  }
  return std::make_pair(frameMax, controlMax);
}

void derive(Row& r, std::size_t sourceFrames, const Bandwidth& bw) {
  const json& s = r.summary;
  r.frames = s.at("frames").get<std::uint64_t>();
  // summary.json does not carry drops; the host prints them, and frames sent
  // plus frames dropped is the sequence's length.
  r.drops = droppedFromLog(r.log);
  if (r.frames + r.drops != sourceFrames)
    spdlog::warn("bench: {}: {} frames sent + {} dropped != {} in the sequence", r.layout.name(), r.frames, r.drops,
                 sourceFrames);
  double maxBytes = 0.0, steadyMax = 0.0, gpSum = 0.0, gpSteadySum = 0.0, gpSteadyMax = 0.0, otherSteadyMax = 0.0;
  std::map<int, double> rankCpuPerWall;
  int gpN = 0;
  r.gpStageCpuMax.assign(kGpStages.size(), 0.0);
  r.gpStageCpuSum.assign(kGpStages.size(), 0.0);
  std::size_t idx = 0;
  for (const json& k : s.at("per_rank")) {
    const double cpu = k.at("cpu_s").get<double>();
    const std::string role = k.at("role").get<std::string>();
    r.cpuSum += cpu;
    if (cpu > r.cpuMax) {
      r.cpuMax = cpu;
      r.cpuMaxRank = fmt::format("{}{}", role, k.at("rank").get<int>());
    }
    if (role == "host") r.hostCpu = cpu;
    if (role == "GP") {
      r.gpCpuMax = std::max(r.gpCpuMax, cpu);
      gpSum += cpu;
      ++gpN;
    }
    const double base = r.baseOk && idx < r.baseCpu.size() ? r.baseCpu[idx] : 0.0;
    const double steady = std::max(0.0, cpu - base);
    steadyMax = std::max(steadyMax, steady);
    r.baseCpuMax = std::max(r.baseCpuMax, base);
    ++idx;
    double busy = 0.0;
    for (const auto& st : kStages)
      if (st != "wait") busy += k.at("stage_ms").at(st).get<double>();
    const double cpuPerWall = busy > 0.0 ? 1e3 * steady / busy : 0.0;
    rankCpuPerWall[k.at("rank").get<int>()] = cpuPerWall;
    if (role != "GP") otherSteadyMax = std::max(otherSteadyMax, steady);
    const double f = static_cast<double>(std::max<std::uint64_t>(r.frames, 1));
    if (role == "GP") {
      gpSteadySum += steady;
      gpSteadyMax = std::max(gpSteadyMax, steady);
      for (std::size_t i = 0; i < kGpStages.size(); ++i) {
        const double ms = k.at("stage_ms").at(kGpStages[i]).get<double>() * cpuPerWall / f;
        r.gpStageCpuMax[i] = std::max(r.gpStageCpuMax[i], ms);
        r.gpStageCpuSum[i] += ms;
      }
    }
    if (role == "PP")
      r.ppCompositeCpuMax =
          std::max(r.ppCompositeCpuMax, k.at("stage_ms").at("composite").get<double>() * cpuPerWall / f);
    if (role == "PP") r.ppCpuMax = std::max(r.ppCpuMax, cpu);
    maxBytes = std::max({maxBytes, k.at("bytes_sent").get<double>(), k.at("bytes_received").get<double>()});
  }
  const double f = static_cast<double>(std::max<std::uint64_t>(r.frames, 1));
  r.maxRankBytesPerFrame = maxBytes / f;
  r.modelCpuMs = 1e3 * r.cpuMax / f;
  r.modelShmMs = r.modelCpuMs + 1e3 * r.maxRankBytesPerFrame / bw.bytesPerS;
  r.modelEthMs = r.modelCpuMs + 1e3 * r.maxRankBytesPerFrame / kEthernetBytesPerS;
  if (r.baseOk) {
    r.steadyCpuMs = 1e3 * steadyMax / f;
    r.steadyShmMs = r.steadyCpuMs + 1e3 * r.maxRankBytesPerFrame / bw.bytesPerS;
    r.steadyEthMs = r.steadyCpuMs + 1e3 * r.maxRankBytesPerFrame / kEthernetBytesPerS;
  }
  if (r.baseOk) {
    const auto sp = splitGpUpdates((fs::path(r.dir) / "stats.csv").string(), rankCpuPerWall);
    if (sp) {
      r.split = true;
      r.gpFrameCpuMs = sp->first / f;
      r.gpControlCpuMs = sp->second;
      r.incrementalCpuMs = std::max(r.gpFrameCpuMs, 1e3 * otherSteadyMax / f);
      r.incrementalEthMs = r.incrementalCpuMs + 1e3 * r.maxRankBytesPerFrame / kEthernetBytesPerS;
    }
  }
  if (r.baseOk) {
    double all = 0.0;
    for (std::size_t i = 0; i < r.baseCpu.size() && i < s.at("per_rank").size(); ++i)
      all += s.at("per_rank")[i].at("cpu_s").get<double>() - r.baseCpu[i];
    r.gpSteadyMaxMs = 1e3 * gpSteadyMax / f;
    r.gpSteadySumMs = 1e3 * gpSteadySum / f;
    r.allSteadySumMs = 1e3 * all / f;
  }
  // Over the GPs' CPU time less start-up where the baseline ran.
  r.gpCpuImbalance = gpN ? (r.baseOk ? (gpSteadySum > 0 ? gpSteadyMax / (gpSteadySum / gpN) : 0.0)
                                     : r.gpCpuMax / (gpSum / gpN))
                         : 0.0;
  // summary.json's imbalance is over every rank with time in a stage, which
  // mixes roles (the host's tile copies count as "composite", its frame sends
  // as "send"); here it is over the role whose work the stage is.
  for (const auto& st : kStages) {
    const std::string role = st == "composite" || st == "receive" ? "PP" : "GP";
    double mx = 0.0, sum = 0.0;
    int n = 0;
    for (const json& k : s.at("per_rank"))
      if (k.at("role").get<std::string>() == role) {
        const double v = k.at("stage_ms").at(st).get<double>();
        mx = std::max(mx, v);
        sum += v;
        ++n;
      }
    r.roleImbalance.push_back(n && sum > 0.0 ? mx / (sum / n) : 0.0);
  }
}

std::vector<double> perRankCpu(const std::string& summaryPath) {
  std::ifstream in(summaryPath);
  const json s = json::parse(in);
  std::vector<double> v;
  for (const json& k : s.at("per_rank")) v.push_back(k.at("cpu_s").get<double>());
  return v;
}

double num(const json& j, const char* key) { return j.contains(key) ? j.at(key).get<double>() : 0.0; }

// ---- the serial reference ------------------------------------------------------------

// `pp5echo run --serial` on the same sequence, one thread: what one core does
// per frame with no messages (the serial path has no scripted view change).
struct SerialRef {
  bool ok = false;
  ChildResult child;
  std::size_t frames = 0;
  double reconMs = 0.0, shadeMs = 0.0, sampleMs = 0.0, compositeMs = 0.0;  // means per frame (wall, one thread)
  std::string log;
};

SerialRef runSerialReference(const std::string& exe, const BenchOptions& o, const Sequence& seq, double timeoutS) {
  SerialRef r;
  const std::string dir = fs::absolute(fs::path(o.outDir) / "layouts" / "serial").string();
  std::error_code ec;
  fs::remove_all(dir, ec);
  makeOutputDir(dir);
  r.log = (fs::path(dir) / "run.log").string();
  std::vector<std::string> argv = {exe, "run", fs::absolute(o.file).string(), "--serial", "-o", dir};
  std::vector<std::string> sets = {"run.source=\"sequence\"", "run.sequence=" + tomlString(seq.sequencePath),
                                   "run.plus_config=" + tomlString(seq.configPath), "render.threads=1",
                                   "recon.threads=1"};
  sets.insert(sets.end(), o.overrides.begin(), o.overrides.end());
  for (const auto& s : sets) {
    argv.push_back("--set");
    argv.push_back(s);
  }
  r.child = runChild(argv, r.log, timeoutS);
  if (r.child.status != 0) return r;
  std::ifstream in(fs::path(dir) / "stats.csv");
  std::string line;
  std::getline(in, line);
  while (std::getline(in, line)) {
    std::vector<double> v;
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) v.push_back(std::strtod(c.c_str(), nullptr));
    if (v.size() < 5) continue;
    r.reconMs += v[1];
    r.shadeMs += v[2];
    r.sampleMs += v[3];
    r.compositeMs += v[4];
    ++r.frames;
  }
  if (r.frames == 0) return r;
  const double n = static_cast<double>(r.frames);
  r.reconMs /= n;
  r.shadeMs /= n;
  r.sampleMs /= n;
  r.compositeMs /= n;
  r.ok = true;
  return r;
}

std::string serialText(const SerialRef& r) {
  if (!r.ok) return fmt::format("the serial reference run failed (exit {}; see {})", r.child.status, r.log);
  return fmt::format("{:.1f} ms CPU per frame over the whole run ({:.1f} s CPU, {:.1f} s wall, {} frames, start-up "
                     "and final pass included); per frame (means, wall): reconstruct {:.1f} + shade {:.1f} + sample "
                     "{:.1f} + composite {:.1f} ms",
                     1e3 * r.child.cpuS / static_cast<double>(r.frames), r.child.cpuS, r.child.wallS, r.frames,
                     r.reconMs, r.shadeMs, r.sampleMs, r.compositeMs);
}

// ---- outputs -----------------------------------------------------------------------

std::vector<std::string> csvHeader() {
  std::vector<std::string> h = {"layout", "gps", "pps", "ranks", "gp_partition", "tile_owner", "tile_size", "pace_fps",
                                "repeat", "target", "status", "frames", "drops", "frames_per_s_in", "images_per_s_out",
                                "latency_ms_median", "latency_ms_p95", "bytes_per_frame", "max_rank_bytes_per_frame"};
  for (const auto& st : kStages) {
    h.push_back(st + "_crit_ms_per_frame");
    h.push_back(st + "_imbalance");
  }
  for (const auto& st : kGpStages) {
    h.push_back("gp_" + st + "_cpu_ms_max");
    h.push_back("gp_" + st + "_cpu_ms_sum");
  }
  h.emplace_back("pp_composite_cpu_ms_max");
  for (const char* c : {"cpu_s_sum", "cpu_s_max", "cpu_max_rank", "host_cpu_s", "gp_cpu_s_max", "pp_cpu_s_max",
                        "gp_cpu_imbalance", "baseline_cpu_s_max", "gp_steady_cpu_ms_max", "gp_steady_cpu_ms_sum",
                        "steady_cpu_ms_sum_all", "stream_s", "total_s", "wall_s", "job_cpu_s",
                        "load_avg_before", "load_avg_after", "model_cpu_ms_per_frame", "model_fps_shm",
                        "model_fps_10gbe", "steady_cpu_ms_per_frame", "steady_fps_shm", "steady_fps_10gbe",
                        "gp_frame_cpu_ms_max", "gp_control_cpu_ms_max", "incremental_cpu_ms_per_frame",
                        "incremental_fps_10gbe"})
    h.emplace_back(c);
  return h;
}

std::vector<std::string> csvRow(const Row& r) {
  const Layout& l = r.layout;
  std::vector<std::string> v = {l.name(),
                                std::to_string(l.gps),
                                std::to_string(l.pps),
                                std::to_string(l.ranks()),
                                l.partition,
                                l.owner,
                                std::to_string(l.tileSize),
                                fmt::format("{:g}", l.paceFps),
                                std::to_string(l.repeat),
                                l.target ? "1" : "0",
                                r.ok ? "ok" : fmt::format("failed({})", r.child.timedOut ? "timeout" : std::to_string(r.child.status))};
  const std::size_t fixed = csvHeader().size() - v.size();
  if (!r.ok) {
    v.resize(v.size() + fixed);
    return v;
  }
  const json& s = r.summary;
  const double f = static_cast<double>(std::max<std::uint64_t>(r.frames, 1));
  auto d = [](double x, int p = 3) { return fmt::format("{:.{}f}", x, p); };
  v.push_back(std::to_string(r.frames));
  v.push_back(std::to_string(r.drops));
  v.push_back(d(num(s, "frames_per_s_in")));
  v.push_back(d(num(s, "images_per_s_out")));
  v.push_back(d(num(s, "latency_ms_median")));
  v.push_back(d(num(s, "latency_ms_p95")));
  v.push_back(d(num(s, "bytes_per_frame"), 0));
  v.push_back(d(r.maxRankBytesPerFrame, 0));
  for (std::size_t i = 0; i < kStages.size(); ++i) {
    const json& x = s.at("stages").at(kStages[i]);
    v.push_back(d(x.at("critical_ms").get<double>() / f));
    v.push_back(d(r.roleImbalance[i]));
  }
  for (std::size_t i = 0; i < kGpStages.size(); ++i) {
    v.push_back(r.baseOk ? d(r.gpStageCpuMax[i]) : "");
    v.push_back(r.baseOk ? d(r.gpStageCpuSum[i]) : "");
  }
  v.push_back(r.baseOk ? d(r.ppCompositeCpuMax) : "");
  v.push_back(d(r.cpuSum));
  v.push_back(d(r.cpuMax));
  v.push_back(r.cpuMaxRank);
  v.push_back(d(r.hostCpu));
  v.push_back(d(r.gpCpuMax));
  v.push_back(d(r.ppCpuMax));
  v.push_back(d(r.gpCpuImbalance));
  v.push_back(r.baseOk ? d(r.baseCpuMax) : "");
  v.push_back(r.baseOk ? d(r.gpSteadyMaxMs) : "");
  v.push_back(r.baseOk ? d(r.gpSteadySumMs) : "");
  v.push_back(r.baseOk ? d(r.allSteadySumMs) : "");
  v.push_back(d(num(s, "stream_s")));
  v.push_back(d(num(s, "total_s")));
  v.push_back(d(r.child.wallS));
  v.push_back(d(r.child.cpuS));
  v.push_back(d(r.loadBefore, 2));
  v.push_back(d(r.loadAfter, 2));
  // Paced runs idle between frames and drop some: no model for them.
  const bool model = l.paceFps == 0.0;
  v.push_back(model ? d(r.modelCpuMs) : "");
  v.push_back(model ? d(1e3 / r.modelShmMs, 2) : "");
  v.push_back(model ? d(1e3 / r.modelEthMs, 2) : "");
  const bool steady = model && r.baseOk;
  v.push_back(steady ? d(r.steadyCpuMs) : "");
  v.push_back(steady ? d(1e3 / r.steadyShmMs, 2) : "");
  v.push_back(steady ? d(1e3 / r.steadyEthMs, 2) : "");
  v.push_back(r.split ? d(r.gpFrameCpuMs) : "");
  v.push_back(r.split ? d(r.gpControlCpuMs) : "");
  v.push_back(r.split && model ? d(r.incrementalCpuMs) : "");
  v.push_back(r.split && model ? d(1e3 / r.incrementalEthMs, 2) : "");
  return v;
}

void writeCsv(const std::string& path, const std::vector<Row>& rows) {
  std::string text;
  auto line = [&](const std::vector<std::string>& cells) {
    for (std::size_t i = 0; i < cells.size(); ++i) {
      const std::string& c = cells[i];
      text += i ? "," : "";
      text += c.find_first_of(",\"") == std::string::npos ? c : "\"" + c + "\"";
    }
    text += "\n";
  };
  line(csvHeader());
  for (const Row& r : rows) line(csvRow(r));
  io::AtomicFile f(path);
  f.write(text);
  f.commit();
}

std::string verdict(const Row& r) {
  if (!r.ok) return "not measured (the run failed)";
  const double fps = num(r.summary, "frames_per_s_in"), p95 = num(r.summary, "latency_ms_p95");
  const bool met = r.drops == 0 && fps >= 29.5 && p95 <= 100.0;
  return fmt::format("**{}**: {:.1f} frames/s in, {} of {} frames dropped, latency median {:.0f} ms, p95 {:.0f} ms",
                     met ? "met" : "not met", fps, r.drops, r.frames + r.drops, num(r.summary, "latency_ms_median"),
                     p95);
}

void writeMarkdown(const std::string& path, const std::vector<Row>& rows, const BenchOptions& o, const Sequence& seq,
                   const Bandwidth& bw, const SerialRef& serial, double benchS) {
  std::string m = "# Partitioning benchmark\n\n";
  std::string cmd = "pp5echo bench " + o.file + " -o " + o.outDir + (o.quick ? " --quick" : "");
  for (const auto& s : o.overrides) cmd += " --set " + s;
  m += fmt::format("Command: `{}` ({} layouts in {}, load average {:.2f} at the end). The sweep: {} frames, "
                   "simulated once into `{}` (read back: identical pixels, poses within {:.1e} mm of the "
                   "simulator's).\n\n",
                   cmd, rows.size(), clockText(benchS), loadAverage(), seq.frames,
                   fs::path(seq.sequencePath).filename().string(), seq.maxPoseError);
  m += fmt::format("The serial pipeline on the same sequence, one thread (`pp5echo run --serial`, no view change): "
                   "{}.\n\n",
                   serialText(serial));
  m += "## The target: 1 host, 2 GP, 1 PP paced at 30 frames/s\n\n"
       "Met when no frame is dropped, frames/s in >= 29.5 (summary.json divides by the time from the first frame "
       "sent to the last image, which adds one latency to the 3 s of a 91-frame sweep at 30 frames/s) and the "
       "latency p95 <= 100 ms.\n\n";
  for (const Row& r : rows)
    if (r.layout.target && r.layout.paceFps > 0.0) m += fmt::format("- `{}`: {}\n", r.layout.name(), verdict(r));
  for (const char* part : {"slab", "tile"}) {
    int runs = 0, met = 0;
    for (const Row& r : rows)
      if (r.layout.target && r.layout.paceFps > 0.0 && r.layout.partition == part) {
        ++runs;
        met += verdict(r).rfind("**met**", 0) == 0 ? 1 : 0;
      }
    if (runs) m += fmt::format("\n{}: the target was met in {} of {} runs.", part, met, runs);
  }
  m += "\n\n## Every layout\n\n";
  m += "CPU: every rank's CPU seconds over the run, summed and the largest; per frame, less each rank's start-up "
       "(its CPU on the first frame alone): the busiest GP, all GPs, all ranks. Model: frames/s with one rank per node "
       "over 10 Gb/s Ethernet, 1000 / (the busiest rank's CPU ms per frame + the busiest rank's MB per frame / "
       "1.25 GB/s), from the CPU of the whole run (*run*), less each rank's start-up (*steady*: its CPU on the first "
       "frame alone), and counting the GPs' frame updates only (*incr.*: no view change or final pass). Paced runs "
       "have none.\n\n";
  m += "| layout | ranks | frames (drops) | frames/s in | images/s out | latency median / p95 ms | MB/frame | "
       "CPU s sum / max | GP CPU ms/frame max / sum | all ranks CPU ms/frame | wall s | model fps run / steady / "
       "incr. |\n";
  m += "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const Row& r : rows) {
    const Layout& l = r.layout;
    if (!r.ok) {
      m += fmt::format("| `{}` | {} | failed: {} | | | | | | | | {:.1f} | |\n", l.name(), l.ranks(),
                       r.child.timedOut ? "timed out" : fmt::format("exit {}", r.child.status), r.child.wallS);
      continue;
    }
    const json& s = r.summary;
    std::string model = "(paced)";
    if (l.paceFps == 0.0)
      model = fmt::format("{:.0f} / {} / {}", 1e3 / r.modelEthMs,
                          r.baseOk ? fmt::format("{:.0f}", 1e3 / r.steadyEthMs) : "-",
                          r.split ? fmt::format("{:.0f}", 1e3 / r.incrementalEthMs) : "-");
    m += fmt::format("| `{}`{} | {} | {} ({}) | {:.1f} | {:.1f} | {:.0f} / {:.0f} | {:.2f} | {:.1f} / {:.1f} | {} | {} | "
                     "{:.1f} | {} |\n",
                     l.name(), l.target ? " *" : "", l.ranks(), r.frames, r.drops, num(s, "frames_per_s_in"),
                     num(s, "images_per_s_out"), num(s, "latency_ms_median"), num(s, "latency_ms_p95"),
                     num(s, "bytes_per_frame") / 1e6, r.cpuSum, r.cpuMax,
                     r.baseOk ? fmt::format("{:.1f} / {:.1f}", r.gpSteadyMaxMs, r.gpSteadySumMs) : "-",
                     r.baseOk ? fmt::format("{:.1f}", r.allSteadySumMs) : "-", r.child.wallS, model);
  }
  m += "\n## Per stage\n\n";
  m += "Wall: the busiest rank's wall-clock ms per frame in the stage (summary.json's critical path), and the "
       "imbalance (max / mean over the GPs; over the PPs for composite). On a shared 2-core machine a rank's wall "
       "time is its CPU time stretched by the cores it did not get, so the CPU columns estimate each GP's CPU ms "
       "per frame in a stage as its wall ms there times its CPU (less start-up) over its busy wall time: the "
       "busiest GP (*max*) and all GPs together (*sum*, the work). Frame / control: the busiest GP's CPU ms per "
       "frame update, and per control update (a full re-shade and re-sample).\n\n";
  m += "| layout | wall recon | wall shade | wall sample | wall composite | CPU recon max / sum | CPU shade max / sum | "
       "CPU sample max / sum | CPU send max / sum | PP composite CPU | GP imb. | GP frame / control ms |\n";
  m += "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const Row& r : rows) {
    if (!r.ok) continue;
    const json& s = r.summary;
    const double f = static_cast<double>(std::max<std::uint64_t>(r.frames, 1));
    auto wall = [&](const char* st) {
      const auto i = static_cast<std::size_t>(std::find(kStages.begin(), kStages.end(), st) - kStages.begin());
      return fmt::format("{:.1f} ({:.2f})", s.at("stages").at(st).at("critical_ms").get<double>() / f,
                         r.roleImbalance[i]);
    };
    auto cpu = [&](std::size_t i) {
      return r.baseOk ? fmt::format("{:.1f} / {:.1f}", r.gpStageCpuMax[i], r.gpStageCpuSum[i]) : std::string("-");
    };
    m += fmt::format("| `{}` | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2f} | {} |\n", r.layout.name(),
                     wall("reconstruct"), wall("shade"), wall("sample"), wall("composite"), cpu(0), cpu(1), cpu(2),
                     cpu(3), r.baseOk ? fmt::format("{:.1f}", r.ppCompositeCpuMax) : "-", r.gpCpuImbalance,
                     r.split ? fmt::format("{:.1f} / {:.0f}", r.gpFrameCpuMs, r.gpControlCpuMs) : "-");
  }
  m += "\n`*` the target layout. ";
  m += fmt::format("bench.csv also has the model over shared memory at {:.2f} GB/s ({}; {}).\n", bw.bytesPerS / 1e9,
                   bw.measured ? "measured here: 2-rank ping-pong of 1 MiB messages, the fastest of 5 blocks of 20"
                               : "assumed",
                   bw.text);
  bool anyFailed = false;
  for (const Row& r : rows)
    if (!r.ok || !r.baseOk) {
      if (!anyFailed) m += "\n## Failed runs\n";
      anyFailed = true;
      if (!r.ok)
        m += fmt::format("\n`{}`: {} after {:.1f} s; log `{}`, which ends:\n\n```\n{}```\n", r.layout.name(),
                         r.child.timedOut ? "timed out" : fmt::format("exit status {}", r.child.status), r.child.wallS,
                         r.log, r.logTail);
      else
        m += fmt::format("\n`{}`: its baseline run (first frame alone) failed: {}; no steady model\n", r.layout.name(),
                         r.baseChild.timedOut ? "timed out" : fmt::format("exit status {}", r.baseChild.status));
    }
  io::AtomicFile f(path);
  f.write(m);
  f.commit();
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
  const ChildResult r = runChild({py, script, csv, o.outDir}, log, 120.0);
  if (r.status != 0) std::printf("bench: plots failed (exit %d):\n%s", r.status, tail(log, 10).c_str());
  else std::printf("%s", tail(log, 10).c_str());
}

// ---- the bench -----------------------------------------------------------------------

int runBench(BenchOptions o) {
  if (o.pingpong) return runPingPong();
  if (o.file.empty()) throw InputError("bench: give the workload's configuration, e.g. configs/bench.toml");
  Settings s;
  ConfigSchema schema;
  registerAll(schema, s);
  loadSettings(schema, o.file, o.overrides);
  if (o.outDir.empty()) o.outDir = s.output.dir;

  std::vector<Layout> all = layouts(o.quick);
  if (!o.only.empty())
    std::erase_if(all, [&](const Layout& l) { return l.name().find(o.only) == std::string::npos; });
  if (o.list) {
    for (const Layout& l : all) std::printf("%s  (%d ranks)\n", l.name().c_str(), l.ranks());
    return 0;
  }
  if (all.empty()) throw InputError(fmt::format("bench: no layout's name contains \"{}\"", o.only));
  const std::string mpirun = findInPath("mpirun");
  if (mpirun.empty()) throw InputError("bench: mpirun is not on PATH (install openmpi-bin)");
  std::error_code ec;
  const std::string exe = fs::read_symlink("/proc/self/exe", ec).string();
  if (ec) throw InputError("bench: cannot find this program through /proc/self/exe");

  makeOutputDir(o.outDir);
  std::signal(SIGINT, onBenchInterrupt);
  std::signal(SIGTERM, onBenchInterrupt);
  const auto start = Clock::now();
  auto elapsed = [&] { return std::chrono::duration<double>(Clock::now() - start).count(); };

  std::printf("bench: simulating the sweep once into %s/sequence\n", o.outDir.c_str());
  std::fflush(stdout);
  const Sequence seq = simulateSequence(s, (fs::path(o.outDir) / "sequence").string());
  std::printf("bench: %zu frames in %.1f s; read back with identical pixels, poses within %.1e mm\n", seq.frames,
              seq.simulateS, seq.maxPoseError);
  const Bandwidth bw = measureBandwidth(mpirun, exe, o.outDir);
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
      std::vector<std::string> argv = {mpirun, "-n", std::to_string(l.ranks()), exe, "run",
                                       fs::absolute(o.file).string(), "-o", dir, "--expect-ranks",
                                       std::to_string(l.ranks())};
      std::vector<std::string> sets = {
          "run.source=\"sequence\"", "run.sequence=" + tomlString(sequence),
          "run.plus_config=" + tomlString(seq.configPath), fmt::format("parallel.gps={}", l.gps),
          fmt::format("parallel.pps={}", l.pps), fmt::format("parallel.gp_partition=\"{}\"", l.partition),
          fmt::format("parallel.tile_owner=\"{}\"", l.owner), fmt::format("parallel.tile_size={}", l.tileSize),
          fmt::format("run.pace_fps={:g}", l.paceFps)};
      sets.insert(sets.end(), o.overrides.begin(), o.overrides.end());
      if (baseline) sets.push_back("run.script=[]");  // one frame: no view change
      for (const std::string& set : sets) {
        argv.push_back("--set");
        argv.push_back(set);
      }
      return argv;
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
      r.baseChild = runChild(argvFor(bdir, seq.firstPath, true), blog, o.timeoutS);
      rankSeconds += r.baseChild.wallS;
      const std::string bsum = (fs::path(bdir) / "summary.json").string();
      if (r.baseChild.status == 0 && fs::exists(bsum)) {
        try {
          r.baseCpu = perRankCpu(bsum);
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
    r.child = runChild(argv, r.log, o.timeoutS);
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
  writeMarkdown(md, rows, o, seq, bw, serial, elapsed());
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
  cmd->add_flag("--pingpong", o->pingpong, "Internal: the MPI ping-pong the bench runs under mpirun")->group("");
  cmd->callback([o, &exitCode] { exitCode = runBench(*o); });
}

}  // namespace pp5::app
