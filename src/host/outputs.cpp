#include "host/outputs.hpp"

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::host {

StatsCsv::StatsCsv(const std::string& path, const std::vector<std::string>& columns)
    : columns_(columns.size()), path_(path) {
  f_ = std::fopen(path.c_str(), "w");
  if (!f_) inputError(path, "cannot write the statistics file");
  for (std::size_t i = 0; i < columns.size(); ++i) std::fprintf(f_, "%s%s", i ? "," : "", columns[i].c_str());
  std::fprintf(f_, "\n");
  std::fflush(f_);
}

StatsCsv::~StatsCsv() {
  if (f_) std::fclose(f_);
}

void StatsCsv::row(const std::vector<double>& values) {
  PP5_CHECK_EQ(values.size(), columns_);
  std::string line;
  for (std::size_t i = 0; i < values.size(); ++i) line += (i ? "," : "") + fmt::format("{:.6g}", values[i]);
  line += "\n";
  if (std::fputs(line.c_str(), f_) < 0 || std::fflush(f_) != 0) inputError(path_, "cannot write a statistics row");
}

}  // namespace pp5::host
