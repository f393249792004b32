#include "benchmark/cost_model.hpp"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

namespace pp5::harness {

namespace fs = std::filesystem;

// stats.csv has a row per GP update; its `control` column marks the updates
// of control changes (view change, final pass). Returns the busiest GP's
// estimated CPU ms over all its frame updates, and the largest mean CPU ms per
// control update.
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
  const std::size_t iRank = col("rank"), iRole = col("role"), iControl = col("control");
  if (iControl >= cols.size()) return std::nullopt;
  std::vector<std::size_t> busy;
  for (const auto& st : kStages)
    if (st != "wait") busy.push_back(col(st + "_ms"));
  for (std::size_t i : busy)
    if (i >= cols.size()) return std::nullopt;
  struct Acc {
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
    if (v[iControl] == 0.0) {
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
  // Frames sent plus frames dropped is the sequence's length.
  r.drops = s.at("dropped_frames").get<std::uint64_t>();
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

std::vector<double> perRankCpu(const json& s) {
  std::vector<double> v;
  for (const json& k : s.at("per_rank")) v.push_back(k.at("cpu_s").get<double>());
  return v;
}

double num(const json& j, const char* key) { return j.contains(key) ? j.at(key).get<double>() : 0.0; }

bool readSerialStats(const std::string& statsCsv, SerialRef& r) {
  std::ifstream in(statsCsv);
  std::string line;
  std::getline(in, line);
  // The columns by name.
  std::vector<std::string> header;
  {
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) header.push_back(c);
  }
  const auto column = [&](const char* name) {
    return static_cast<std::size_t>(std::find(header.begin(), header.end(), name) - header.begin());
  };
  const std::size_t cols[4] = {column("recon_ms"), column("shade_ms"), column("sample_ms"), column("composite_ms")};
  for (const std::size_t c : cols)
    if (c >= header.size()) return false;
  double* sums[4] = {&r.reconMs, &r.shadeMs, &r.sampleMs, &r.compositeMs};
  while (std::getline(in, line)) {
    std::vector<double> v;
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) v.push_back(std::strtod(c.c_str(), nullptr));
    if (v.size() < header.size()) continue;
    for (int k = 0; k < 4; ++k) *sums[k] += v[cols[k]];
    ++r.frames;
  }
  if (r.frames == 0) return false;
  const double n = static_cast<double>(r.frames);
  r.reconMs /= n;
  r.shadeMs /= n;
  r.sampleMs /= n;
  r.compositeMs /= n;
  return true;
}

std::string serialText(const SerialRef& r) {
  if (!r.ok) return fmt::format("the serial reference run failed (exit {}; see {})", r.child.status, r.log);
  return fmt::format("{:.1f} ms CPU per frame over the whole run ({:.1f} s CPU, {:.1f} s wall, {} frames, start-up "
                     "and final pass included); per frame (means, wall): reconstruct {:.1f} + shade {:.1f} + sample "
                     "{:.1f} + composite {:.1f} ms",
                     1e3 * r.child.cpuS / static_cast<double>(r.frames), r.child.cpuS, r.child.wallS, r.frames,
                     r.reconMs, r.shadeMs, r.sampleMs, r.compositeMs);
}

}  // namespace pp5::harness
