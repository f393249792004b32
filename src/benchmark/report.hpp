#pragma once
// The benchmark's tables: bench.csv (a row per layout) and summary.md (the
// target's verdict, every layout, per stage, failed runs).
#include <string>
#include <vector>

#include "benchmark/cost_model.hpp"

namespace pp5::harness {

// What summary.md says about the whole bench.
struct ReportContext {
  std::string command;             // how the bench was run
  std::size_t sequenceFrames = 0;  // the sweep, simulated once
  std::string sequencePath;
  double maxPoseError = 0.0;       // mm: the sequence read back against the simulator
  Bandwidth bandwidth;
  SerialRef serial;
  double benchS = 0.0;             // the bench's wall time
};

std::vector<std::string> csvHeader();
// One layout's cells, as many as csvHeader() has; a failed run leaves its
// measurements empty.
std::vector<std::string> csvRow(const Row& r);
void writeCsv(const std::string& path, const std::vector<Row>& rows);
// "**met**: ..." when the paced target held (no drop, >= 29.5 frames/s in,
// latency p95 <= 100 ms), "**not met**: ..." otherwise.
std::string verdict(const Row& r);
void writeMarkdown(const std::string& path, const std::vector<Row>& rows, const ReportContext& context);

}  // namespace pp5::harness
