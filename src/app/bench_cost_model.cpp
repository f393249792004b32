// `pp5echo bench CONFIG --cost-model`: the predictive cost model (issue 17).
//  1. The sweep, made longer (frames every 0.5 mm) so that a layout streams
//     for seconds, with one GP update per frame (parallel.batch_frames = 1)
//     and no scripted view change: what is fitted is the incremental update.
//  2. A census of its work on the serial pipeline (run --serial --census).
//  3. The fit layouts run (shared memory, two of them over TCP too); per-unit
//     CPU costs by role are fitted to every rank's CPU seconds.
//  4. The other layouts are predicted first, then run, and the error of the
//     predicted frames/s is reported; then what one rank per core on a
//     cluster would sustain, for those and for larger layouts never run.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "reconstruction/kernels.hpp"
#include "app/bench_common.hpp"
#include "app/settings.hpp"
#include "core/error.hpp"
#include "core/io_util.hpp"
#include "benchmark/child_process.hpp"
#include "benchmark/cost_fit.hpp"
#include "pipeline/parallel_settings.hpp"
#include "reconstruction/reconstruction.hpp"

namespace pp5::app {

namespace {

namespace fs = std::filesystem;
using namespace pp5::harness;
using nlohmann::json;

// The workload's settings, before the user's --set.
const std::vector<std::string> kWorkload = {"sim.sweep.capture_interval_mm=0.5", "parallel.batch_frames=1",
                                            "run.script=[]", "run.pace_fps=0", "parallel.composite_on=\"tick\""};

// One layout's runs (run.repeats of them, taken round-robin with the other
// layouts of its set, so that the machine's drift spreads over all).
struct Measured {
  Measured(const Layout& l, bool fitted) : layout(l), fit(fitted) {}
  Layout layout;
  bool fit = false;
  std::vector<Observation> runs;  // the runs that succeeded
  Prediction pred;                // predicted layouts: before their first run
  std::string log, why;           // the last failure
  bool ok() const { return !runs.empty(); }
  // The median of the runs' frames/s.
  double framesPerS() const {
    std::vector<double> v;
    for (const Observation& o : runs) v.push_back(o.framesPerS);
    std::sort(v.begin(), v.end());
    if (v.empty()) return 0.0;
    return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  }
  std::string runsText() const {
    std::string t;
    for (const Observation& o : runs) t += fmt::format("{}{:.1f}", t.empty() ? "" : ", ", o.framesPerS);
    return t;
  }
};

Layout tcpOf(Layout l) {
  l.tcp = true;
  return l;
}

// Fitted on 1 to 3 GPs and 1 or 2 PPs, both partitionings, two over TCP;
// predicted: more GPs or PPs than the fit saw, other tile owners and sizes,
// and TCP on other layouts.
std::vector<Layout> fitLayouts(bool quick) {
  if (quick) return {makeLayout(1, 1, "slab"), makeLayout(2, 1, "tile"), makeLayout(2, 2, "slab")};
  std::vector<Layout> v;
  for (const auto& [g, p] : std::vector<std::pair<int, int>>{{1, 1}, {2, 1}, {3, 1}, {2, 2}})
    for (const char* part : {"slab", "tile"}) v.push_back(makeLayout(g, p, part));
  v.push_back(tcpOf(makeLayout(2, 1, "slab")));
  v.push_back(tcpOf(makeLayout(2, 2, "tile")));
  return v;
}

std::vector<Layout> predictLayouts(bool quick) {
  if (quick) return {makeLayout(3, 1, "slab")};
  std::vector<Layout> v;
  for (const auto& [g, p] : std::vector<std::pair<int, int>>{{5, 1}, {2, 3}, {4, 2}})
    for (const char* part : {"slab", "tile"}) v.push_back(makeLayout(g, p, part));
  v.push_back(makeLayout(2, 2, "slab", "interleaved"));
  v.push_back(makeLayout(3, 1, "tile", "interleaved"));
  v.push_back(makeLayout(2, 2, "slab", "contiguous", 64));
  v.push_back(makeLayout(2, 2, "tile", "contiguous", 256));
  for (const char* part : {"slab", "tile"}) v.push_back(tcpOf(makeLayout(3, 1, part)));
  return v;
}

// Runs one layout once; a run that succeeds adds an observation to m.
void runLayout(const CostModelRun& run, const std::vector<std::string>& overrides, const sim::SimulatedSweep& seq,
               Measured& m) {
  const std::string dir = fs::absolute(fs::path(run.outDir) / "layouts" / m.layout.name() /
                                       fmt::format("run{}", m.runs.size() + 1))
                              .string();
  std::error_code ec;
  fs::remove_all(dir, ec);
  makeOutputDir(dir);
  m.log = (fs::path(dir) / "run.log").string();
  const ChildResult r = runChild(
      layoutArgv(run.mpirun, run.exe, run.file, overrides, seq.configPath, m.layout, dir, seq.sequencePath, false),
      m.log, run.timeoutS, run.stop);
  const std::string sum = (fs::path(dir) / "summary.json").string();
  if (r.status != 0 || !fs::exists(sum)) {
    m.why = r.timedOut ? "timed out" : fmt::format("exit status {}", r.status);
    return;
  }
  try {
    std::ifstream in(sum);
    const json s = json::parse(in);
    Observation o;
    o.layout = m.layout;
    for (const json& k : s.at("per_rank")) {
      o.cpuS.push_back(k.at("stream_cpu_s").get<double>());
      o.bytesMoved.push_back(k.at("stream_bytes").get<double>());
    }
    o.framesPerS = s.at("frames_per_s_in").get<double>();
    o.streamS = o.framesPerS > 0 ? s.at("frames").get<double>() / o.framesPerS : 0.0;
    if (s.at("dropped_frames").get<double>() > 0) throw InputError("frames were dropped");
    if (o.framesPerS <= 0) throw InputError("no frames/s in it");
    m.runs.push_back(std::move(o));
  } catch (const std::exception& e) {
    m.why = fmt::format("{}: {}", sum, e.what());
  }
}

// Every layout of a set run.repeats times, round-robin.
void runSet(const CostModelRun& run, const std::vector<std::string>& overrides, const sim::SimulatedSweep& seq,
            std::vector<Measured>& set, std::size_t& done, std::size_t total) {
  for (int k = 0; k < run.repeats; ++k)
    for (Measured& m : set) {
      if (run.stop && *run.stop) return;
      std::printf("cost model: [%zu/%zu] %s %s, run %d of %d\n", ++done, total, m.fit ? "fit on" : "predicted",
                  m.layout.name().c_str(), k + 1, run.repeats);
      std::fflush(stdout);
      const std::size_t before = m.runs.size();
      runLayout(run, overrides, seq, m);
      if (m.runs.size() > before)
        std::printf("cost model:   %.1f frames/s measured%s\n", m.runs.back().framesPerS,
                    m.fit ? "" : fmt::format(" (predicted {:.1f})", m.pred.framesPerS).c_str());
      else
        std::printf("cost model:   FAILED (%s); the log %s ends:\n%s", m.why.c_str(), m.log.c_str(),
                    tail(m.log, 10).c_str());
    }
}

std::string pct(double predicted, double measured) {
  return measured > 0 ? fmt::format("{:+.0f}%", 100.0 * (predicted - measured) / measured) : "-";
}

}  // namespace

int runCostModel(const CostModelRun& run) {
  makeOutputDir(run.outDir);
  std::vector<std::string> overrides = kWorkload;
  overrides.insert(overrides.end(), run.overrides.begin(), run.overrides.end());
  Settings s;
  ConfigSchema schema;
  registerAll(schema, s);
  loadSettings(schema, run.file, overrides);
  const int cores = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  // rankWork splits work as these settings do; refuse the others rather than mispredict.
  if (s.parallel.split() != parallel::SlabSplit::Longest || s.parallel.ghostVoxels != 1 ||
      !gp::kernelFor(s.recon.method).tentKernel)
    throw InputError("cost model: it splits work as parallel.slab_split = \"longest\", parallel.ghost_voxels = 1 and "
                     "recon.method = \"tent\" do; this configuration sets another");

  std::printf("cost model: simulating the sweep once (frames every 0.5 mm) into %s/sequence\n", run.outDir.c_str());
  std::fflush(stdout);
  const sim::SimulatedSweep seq = sim::simulateSweep(s.sim, sweepGridOf(s), (fs::path(run.outDir) / "sequence").string());
  std::printf("cost model: %zu frames in %.1f s\n", seq.frames, seq.simulateS);
  const Bandwidth shm = measureBandwidth(run.mpirun, run.exe, run.outDir, false, run.stop);
  const Bandwidth tcp = measureBandwidth(run.mpirun, run.exe, run.outDir, true, run.stop);
  std::printf("cost model: MPI ping-pong, shared memory: %s\ncost model: MPI ping-pong, TCP: %s\n", shm.text.c_str(),
              tcp.text.c_str());

  // The census, on the serial pipeline.
  const std::string cdir = fs::absolute(fs::path(run.outDir) / "census").string();
  makeOutputDir(cdir);
  const std::string censusPath = (fs::path(cdir) / "census.json").string();
  std::printf("cost model: counting the sweep's work on the serial pipeline (census)\n");
  std::fflush(stdout);
  const ChildResult cr =
      runChild(serialArgv(run.exe, run.file, overrides, seq, cdir, censusPath), (fs::path(cdir) / "run.log").string(),
               run.timeoutS, run.stop);
  if (cr.status != 0)
    throw InputError(fmt::format("cost model: the census run failed (exit {}); its log {} ends:\n{}", cr.status,
                                 (fs::path(cdir) / "run.log").string(), tail((fs::path(cdir) / "run.log").string(), 10)));
  const Census census = readCensus(censusPath);
  double reconTotal = 0.0, samplesTotal = 0.0;
  for (double v : census.recon[0]) reconTotal += v;
  for (double v : census.samples[0]) samplesTotal += v;
  std::printf("cost model: census: %.0f frames, %.0f dirty voxels and %.0f samples per frame\n", census.frames,
              reconTotal / census.frames, samplesTotal / census.frames);

  std::vector<Measured> fits, preds;
  for (const Layout& l : fitLayouts(run.quick)) fits.emplace_back(l, true);
  for (const Layout& l : predictLayouts(run.quick)) preds.emplace_back(l, false);
  const std::size_t total = (fits.size() + preds.size()) * static_cast<std::size_t>(run.repeats);
  std::size_t done = 0;
  runSet(run, overrides, seq, fits, done, total);
  std::vector<Observation> obs;
  std::size_t fitted = 0;
  for (const Measured& m : fits) {
    obs.insert(obs.end(), m.runs.begin(), m.runs.end());
    fitted += m.ok() ? 1 : 0;
  }
  if (run.stop && *run.stop) return 130;
  if (fitted < 3) throw InputError("cost model: fewer than 3 fit layouts ran; nothing to fit");
  const UnitCosts u = fitCosts(census, obs);
  std::printf("cost model: fitted on %zu ranks of %zu runs; per-unit CPU (ns): GP frame %.0f, reconstructed voxel "
              "%.2f, scanned voxel %.2f, sample %.1f, TCP byte %.3f; PP sample %.1f, screen-second %.3g, second %.3g, "
              "TCP byte %.3f; host frame %.0f, pixel byte %.3f, TCP byte %.3f\n",
              u.observations, obs.size(), u.gp[0] * 1e9, u.gp[1] * 1e9, u.gp[2] * 1e9, u.gp[3] * 1e9, u.gp[4] * 1e9,
              u.pp[0] * 1e9, u.pp[1] * 1e9, u.pp[2] * 1e9, u.pp[3] * 1e9, u.host[0] * 1e9, u.host[1] * 1e9,
              u.host[2] * 1e9);
  // Every prediction is made before any predicted layout runs.
  for (Measured& m : fits) m.pred = predict(census, m.layout, u, cores);
  for (Measured& m : preds) m.pred = predict(census, m.layout, u, cores);
  runSet(run, overrides, seq, preds, done, total);

  // The tables.
  constexpr double k10GbE = 10e9 / 8.0;
  const std::string md = (fs::path(run.outDir) / "cost_model.md").string();
  const std::string csv = (fs::path(run.outDir) / "cost_model.csv").string();
  std::ofstream m(md), c(csv);
  c << "layout,set,ranks,runs,measured_fps_median,predicted_fps,error_pct,busiest_rank,bound,cluster_fps_shm,cluster_fps_tcp,"
       "cluster_fps_10gbe\n";
  m << "# Cost model (issue 17)\n\n";
  m << fmt::format("Command: `pp5echo bench {} --cost-model -o {}{}`. Workload: `{}` with {}; {} frames, each layout run {} "
                   "times round-robin. This machine: {} cores. Ping-pong, shared memory: {}. TCP "
                   "(`--mca pml ob1 --mca btl tcp,self`): {}.\n\n",
                   run.file, run.outDir, run.quick ? " --quick" : "", run.file, fmt::join(kWorkload, ", "), seq.frames,
                   run.repeats, cores, shm.text, tcp.text);
  m << fmt::format("Census (serial pipeline, one thread): {:.0f} dirty voxels and {:.0f} samples per frame.\n\n",
                   reconTotal / census.frames, samplesTotal / census.frames);
  m << "Fitted per-unit CPU costs (non-negative least squares over every rank of the fit layouts, on the CPU each "
       "rank spent on the stream of frames, `stream_cpu_s`; ns per unit):\n\n";
  m << "| role | per unit | ns | rms residual s |\n|---|---|---:|---:|\n";
  const char* gpUnits[] = {"frame", "reconstructed voxel", "scanned dirty voxel", "sample", "TCP byte"};
  for (int i = 0; i < 5; ++i)
    m << fmt::format("| GP | {} | {:.3g} | {} |\n", gpUnits[i], u.gp[static_cast<std::size_t>(i)] * 1e9,
                     i ? "" : fmt::format("{:.3f}", u.rmsResidualS[1]));
  const char* ppUnits[] = {"sample received", "second of stream x screen owned (ticks)", "second of stream",
                           "TCP byte"};
  for (int i = 0; i < 4; ++i)
    m << fmt::format("| PP | {} | {:.3g} | {} |\n", ppUnits[i], u.pp[static_cast<std::size_t>(i)] * 1e9,
                     i ? "" : fmt::format("{:.3f}", u.rmsResidualS[2]));
  const char* hostUnits[] = {"frame", "pixel byte sent", "TCP byte"};
  for (int i = 0; i < 3; ++i)
    m << fmt::format("| host | {} | {:.3g} | {} |\n", hostUnits[i], u.host[static_cast<std::size_t>(i)] * 1e9,
                     i ? "" : fmt::format("{:.3f}", u.rmsResidualS[0]));
  m << fmt::format("\nWire sizes: {:.2f} bytes per sample (GP to PP), {:.0f} tile bytes per second of stream and "
                   "whole screen (PP to host).\n\n",
                   u.bytesPerSample, u.tileBytesPerS);
  m << "Frames/s: measured on this machine, and predicted from the census and the fitted costs before the layout ran "
       "(the stream lasts as long as the busiest rank's CPU or every rank's CPU over the cores, whichever is longer). "
       "Cluster: one rank per core, each rank's CPU plus its bytes over the link (not overlapped), for the measured "
       "shared-memory ping-pong, and over TCP (its per-byte CPU included) for the measured TCP ping-pong and for 10 "
       "Gb/s Ethernet.\n\n";
  m << "| layout | set | ranks | measured: median (runs) | predicted | error | busiest (bound) | cluster, shm link | cluster, TCP link "
       "| cluster, 10 GbE |\n|---|---|---:|---:|---:|---:|---|---:|---:|---:|\n";
  int within = 0, predicted = 0;
  auto row = [&](const Measured& x) {
    const Prediction& p = x.pred;
    const std::string busiest =
        p.rankCpuS.empty() ? "-"
                           : fmt::format("rank {} ({})", p.busiest, p.coreBound ? fmt::format("{} cores", cores) : "rank");
    // One rank per core, over shared memory or over TCP (whose bytes cost CPU too).
    Layout viaShm = x.layout, viaTcp = x.layout;
    viaShm.tcp = false;
    viaTcp.tcp = true;
    const Prediction ps = predict(census, viaShm, u, x.layout.ranks()), pt = predict(census, viaTcp, u, x.layout.ranks());
    const double cs = clusterRate(census, ps, shm.bytesPerS).framesPerS,
                 ct = clusterRate(census, pt, tcp.bytesPerS).framesPerS, ce = clusterRate(census, pt, k10GbE).framesPerS;
    const double measured = x.framesPerS();
    const std::string meas = x.ok() ? fmt::format("{:.1f} ({})", measured, x.runsText()) : "failed";
    m << fmt::format("| {} | {} | {} | {} | {:.1f}{} | {} | {} | {:.0f} | {:.0f} | {:.0f} |\n", x.layout.name(),
                     x.fit ? "fit" : "predicted", x.layout.ranks(), meas, p.framesPerS,
                     p.converged ? "" : " (did not settle)", x.ok() ? pct(p.framesPerS, measured) : "-", busiest, cs,
                     ct, ce);
    c << fmt::format("{},{},{},{},{},{:.2f},{},{},{},{:.1f},{:.1f},{:.1f}\n", x.layout.name(),
                     x.fit ? "fit" : "predicted", x.layout.ranks(), x.runs.size(),
                     x.ok() ? fmt::format("{:.2f}", measured) : "", p.framesPerS,
                     x.ok() ? fmt::format("{:.1f}", 100.0 * (p.framesPerS - measured) / measured) : "", p.busiest,
                     p.coreBound ? "cores" : "rank", cs, ct, ce);
    if (!x.fit && x.ok()) {
      ++predicted;
      if (std::abs(p.framesPerS - measured) <= 0.25 * measured) ++within;
    }
  };
  for (const Measured& x : fits) row(x);
  for (const Measured& x : preds) row(x);
  m << fmt::format("\n**{} of {} predicted layouts within 25% of the measured frames/s.**\n\n", within, predicted);

  // Larger layouts, never run: one rank per core on nodes of 16 cores.
  m << "What one rank per core would sustain on a cluster (predicted, never run; over TCP, its per-byte CPU "
       "included; nodes of 16 cores, every link taken as the network's; the limit: the rank whose CPU and bytes take "
       "longest):\n\n| layout | ranks | nodes | "
       "busiest rank CPU ms/frame | frames/s, TCP link (limit) | frames/s, 10 GbE (limit) |\n|---|---:|---:|---:|---:|---:|\n";
  std::printf("cost model: one rank per core on a cluster (predicted):\n");
  for (const auto& [g, p] : std::vector<std::pair<int, int>>{{6, 1}, {12, 3}, {24, 7}, {48, 15}, {96, 31}})
    for (const char* part : {"slab", "tile"}) {
      const Layout l = tcpOf(makeLayout(g, p, part));  // a cluster's network: TCP, whose bytes cost CPU
      const Prediction pr = predict(census, l, u, l.ranks());
      const double worst = *std::max_element(pr.rankCpuS.begin(), pr.rankCpuS.end());
      const ClusterRate ft = clusterRate(census, pr, tcp.bytesPerS), fe = clusterRate(census, pr, k10GbE);
      const std::vector<RankWork> w = rankWork(census, l);
      auto limit = [&](const ClusterRate& r) {
        return fmt::format("{:.0f} ({} {})", r.framesPerS, roleName(w[static_cast<std::size_t>(r.limit)].role), r.limit);
      };
      m << fmt::format("| {} | {} | {} | {:.2f} | {} | {} |\n", l.name(), l.ranks(), (l.ranks() + 15) / 16,
                       1e3 * worst / census.frames, limit(ft), limit(fe));
      std::printf("  %-28s %3d ranks: %s frames/s over TCP, %s over 10 GbE\n", l.name().c_str(), l.ranks(),
                  limit(ft).c_str(), limit(fe).c_str());
    }
  m.close();
  c.close();
  std::printf("cost model: %d of %d predicted layouts within 25%% of the measured frames/s\nwrote %s and %s\n", within,
              predicted, md.c_str(), csv.c_str());
  if (run.stop && *run.stop) return 130;
  return 0;
}

}  // namespace pp5::app
