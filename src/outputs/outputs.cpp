#include "outputs/outputs.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cstring>
#include <ctime>
#include <filesystem>

#include "core/error.hpp"
#include "core/io_util.hpp"

namespace pp5::host {

namespace fs = std::filesystem;

bool isRunOutput(const std::string& n) {
  auto ext = [&](const char* prefix, const char* suffix) {
    return io::startsWith(n, prefix) && io::endsWith(n, suffix) && n.size() > std::strlen(prefix) + std::strlen(suffix);
  };
  for (const char* fixed : {"buildup.gif", "orbit.gif", "volume.mha", "stats.csv", "summary.json", "settings.toml",
                            RunFolder::kIncompleteMarker})
    if (n == fixed) return true;
  return ext("final_", ".png") || ext("mpr_", ".png");
}

void createOutputFolder(const std::string& dir) {
  if (dir.empty()) throw InputError("the output folder is empty: set output.dir or give -o DIR");
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    inputError(dir, "cannot create the output folder{}", ec ? " (" + ec.message() + ")" : std::string());
}

RunFolder::RunFolder(const std::string& dir) : dir_(dir) {
  createOutputFolder(dir);
  std::error_code ec;
  // The marker goes first: written, it also shows that the folder takes files.
  markedBefore_ = fs::exists(fs::path(dir) / kIncompleteMarker, ec);  // an earlier run was cut off
  try {
    io::AtomicFile marker((fs::path(dir) / kIncompleteMarker).string());
    const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    char when[64] = "";
    std::strftime(when, sizeof when, "%Y-%m-%d %H:%M:%S", std::localtime(&now));
    marker.write(fmt::format(
        "A pp5echo run started writing to this folder at {} and has not finished.\n"
        "Until it does (this file is then removed), the outputs here are incomplete.\n"
        "A run that was cut off leaves this file; a recording it made is kept as\n"
        "recording.mha, or as recording.mha.journal (pp5echo restore recording.mha.journal).\n",
        when));
    marker.commit();
  } catch (const InputError& e) {
    inputError(dir, "cannot write in the output folder: {}", e.what());
  }
}

void RunFolder::start(const std::vector<std::string>& keep) {
  started_ = true;
  std::error_code ec;
  auto kept = [&](const fs::path& p) {
    for (const auto& k : keep)
      if (!k.empty() && fs::exists(k, ec) && fs::equivalent(p, k, ec)) return true;
    return false;
  };
  std::vector<fs::path> earlier;
  for (const auto& e : fs::directory_iterator(dir_, ec))
    if (e.is_regular_file(ec) && isRunOutput(e.path().filename().string()) &&
        e.path().filename() != kIncompleteMarker && !kept(e.path()))
      earlier.push_back(e.path());
  for (const auto& p : earlier)
    if (!fs::remove(p, ec) && ec) inputError(p.string(), "cannot remove an earlier run's output ({})", ec.message());
  if (!earlier.empty())
    spdlog::info("run: removed {} output{} an earlier run left in {}", earlier.size(), earlier.size() == 1 ? "" : "s",
                 dir_);
}

RunFolder::~RunFolder() {
  if (started_ || finished_ || markedBefore_) return;
  std::error_code ec;
  fs::remove(fs::path(dir_) / kIncompleteMarker, ec);  // refused before it changed anything
}

void RunFolder::finished() {
  finished_ = true;
  std::error_code ec;
  fs::remove(fs::path(dir_) / kIncompleteMarker, ec);
  if (ec) inputError(dir_, "cannot remove {} after the run ({})", kIncompleteMarker, ec.message());
}

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
