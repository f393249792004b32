#pragma once
// A run's output folder, and the per-frame statistics file a run writes (its
// slices: outputs/slices.hpp).
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

namespace pp5::host {

// One CSV row per frame (header first), flushed as it goes, so a long run can
// be watched and an interrupted one keeps its rows.
class StatsCsv {
public:
  explicit StatsCsv(const std::string& path, const std::vector<std::string>& columns);
  ~StatsCsv();
  StatsCsv(const StatsCsv&) = delete;
  StatsCsv& operator=(const StatsCsv&) = delete;
  void row(const std::vector<double>& values);  // as many values as columns

private:
  std::FILE* f_ = nullptr;
  std::size_t columns_ = 0;
  std::string path_;
};

// Creates an output folder and its parents; InputError naming it when it
// cannot be (and when the name is empty).
void createOutputFolder(const std::string& dir);

// The folder a run writes its outputs to, from the start of the run to its
// end. Opening it creates it and marks it unfinished with kIncompleteMarker,
// which also shows that it takes files (a read-only folder fails here, before
// any work). start() then removes what an earlier run left there (its images,
// volume, statistics and settings; never a recording, a recording's journal,
// or a file in `keep`, such as the run's own settings file), and finished()
// removes the marker once every output is in place; destroyed before start()
// (the run was refused), it removes the marker again and has changed nothing.
// So a run that failed or was killed never leaves a folder that looks
// complete, nor old images beside new statistics.
class RunFolder {
public:
  static constexpr const char* kIncompleteMarker = "RUN_INCOMPLETE.txt";
  explicit RunFolder(const std::string& dir);
  ~RunFolder();
  RunFolder(const RunFolder&) = delete;
  RunFolder& operator=(const RunFolder&) = delete;
  void start(const std::vector<std::string>& keep);
  void finished();
  const std::string& dir() const { return dir_; }

private:
  std::string dir_;
  bool markedBefore_ = false;  // an earlier run in this folder had not finished
  bool started_ = false;
  bool finished_ = false;
};

// True for a file an earlier run wrote and RunFolder clears: buildup.gif,
// orbit.gif, final_*.png, mpr_*.png, volume.mha, stats.csv, summary.json,
// settings.toml and the marker.
bool isRunOutput(const std::string& fileName);

}  // namespace pp5::host
