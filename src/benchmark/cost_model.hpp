#pragma once
// The benchmark's cost model: from one layout's summary.json and stats.csv
// (and the same layout's run on the first frame alone, its start-up), the
// CPU each rank spends per frame, by stage and by update kind, and the
// frames/s a cluster with one rank per node would reach: 1000 / (the busiest
// rank's CPU ms per frame + its bytes per frame over the link).
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "benchmark/child_process.hpp"
#include "benchmark/layouts.hpp"

namespace pp5::harness {

using nlohmann::json;

// A cluster link, for the cost model's second estimate (stated in summary.md).
inline constexpr double kEthernetBytesPerS = 10e9 / 8.0;  // 10 Gb/s Ethernet
// The pipeline's stages, in the order summary.json lists them.
inline const std::vector<std::string> kStages = {"receive", "reconstruct", "shade", "sample", "send", "wait", "composite"};
// The GP's stages whose CPU time bench.csv estimates.
inline const std::vector<std::string> kGpStages = {"reconstruct", "shade", "sample", "send"};

// The MPI link between two ranks, from a ping-pong.
struct Bandwidth {
  double bytesPerS = 0.0;   // 1 MiB messages
  double latencyS = 0.0;    // 8-byte messages, one way
  bool measured = false;
  std::string text;
};

// One layout's run and what the model derives from it.
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

// Fills r's derived fields from r.summary (its summary.json), r.baseCpu and
// the run's stats.csv in r.dir. sourceFrames: the sequence's length, which
// frames sent plus dropped must equal.
void derive(Row& r, std::size_t sourceFrames, const Bandwidth& bw);
// The busiest GP's estimated CPU ms over all its frame updates and the
// largest mean CPU ms per control update, from stats.csv (`control` column),
// each GP's wall ms scaled by cpuPerWall[rank]; nullopt when the file lacks
// the columns or GP rows.
std::optional<std::pair<double, double>> splitGpUpdates(const std::string& statsCsv,
                                                        const std::map<int, double>& cpuPerWall);
// Every rank's CPU seconds, from a summary.json.
std::vector<double> perRankCpu(const json& summary);
// A number of a JSON object, 0 when absent.
double num(const json& j, const char* key);

// `pp5echo run --serial` on the same sequence, one thread: what one core does
// per frame with no messages (the serial path has no scripted view change).
struct SerialRef {
  bool ok = false;
  ChildResult child;
  std::size_t frames = 0;
  double reconMs = 0.0, shadeMs = 0.0, sampleMs = 0.0, compositeMs = 0.0;  // means per frame (wall, one thread)
  std::string log;
};
// Means of the serial run's stats.csv (reconstruct, shade, sample and
// composite ms per frame, its columns 1 to 4) into r; false when it has no rows.
bool readSerialStats(const std::string& statsCsv, SerialRef& r);
std::string serialText(const SerialRef& r);

}  // namespace pp5::harness
