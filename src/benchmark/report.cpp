#include "benchmark/report.hpp"

#include <algorithm>
#include <filesystem>

#include <fmt/format.h>

#include "core/io_util.hpp"

namespace pp5::harness {

namespace fs = std::filesystem;

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

void writeMarkdown(const std::string& path, const std::vector<Row>& rows, const ReportContext& c) {
  std::string m = "# Partitioning benchmark\n\n";
  m += fmt::format("Command: `{}` ({} layouts in {}, load average {:.2f} at the end). The sweep: {} frames, "
                   "simulated once into `{}` (read back: identical pixels, poses within {:.1e} mm of the "
                   "simulator's).\n\n",
                   c.command, rows.size(), clockText(c.benchS), loadAverage(), c.sequenceFrames,
                   fs::path(c.sequencePath).filename().string(), c.maxPoseError);
  m += fmt::format("The serial pipeline on the same sequence, one thread (`pp5echo run --serial`, no view change): "
                   "{}.\n\n",
                   serialText(c.serial));
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
  m += fmt::format("bench.csv also has the model over shared memory at {:.2f} GB/s ({}; {}).\n",
                   c.bandwidth.bytesPerS / 1e9, c.bandwidth.measured ? "measured here: 2-rank ping-pong of 1 MiB messages, the fastest of 5 blocks of 20"
                               : "assumed",
                   c.bandwidth.text);
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

}  // namespace pp5::harness
