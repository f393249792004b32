#pragma once
// The per-frame statistics file a run writes (its slices: host/slices.hpp).
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

}  // namespace pp5::host
