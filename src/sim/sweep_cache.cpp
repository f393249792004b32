#include "sim/sweep_cache.hpp"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <random>
#include <string_view>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "core/config.hpp"
#include "core/error.hpp"
#include "core/io_util.hpp"
#include "formats/plus_config.hpp"
#include "formats/posed_sequence.hpp"
#include "formats/sequence_io.hpp"
#include "sim/simulate.hpp"

namespace pp5::sim {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

PlusVolumeReconstruction reconstructionElement(const Grid& g) {
  PlusVolumeReconstruction r;
  r.outputSpacing = g.spacing;
  r.outputOrigin = g.origin;
  r.outputExtent = std::array<int, 6>{0, static_cast<int>(g.dims.x - 1), 0, static_cast<int>(g.dims.y - 1), 0,
                                      static_cast<int>(g.dims.z - 1)};
  r.interpolation = PlusInterpolation::Linear;
  return r;
}

std::string stem(const SimSettings& s) { return std::string(enumName(s.phantom)); }

SimulatedSweep pathsIn(const SimSettings& s, const std::string& dir) {
  SimulatedSweep out;
  out.sequencePath = fs::absolute(fs::path(dir) / (stem(s) + "_sweep.igs.mha")).string();
  out.configPath = fs::absolute(fs::path(dir) / (stem(s) + "_config.xml")).string();
  out.firstPath = fs::absolute(fs::path(dir) / (stem(s) + "_first_frame.igs.mha")).string();
  return out;
}

// FNV-1a, 64 bits: stable across compilers and runs, unlike std::hash.
std::uint64_t fnv1a(const std::string& text) {
  std::uint64_t h = 0xcbf29ce484222325ull;
  for (const unsigned char c : text) {
    h ^= c;
    h *= 0x100000001b3ull;
  }
  return h;
}

// Keeps the kKeep most recently used sweeps of a phantom, and any used in the
// last kGrace (a run may still be reading it): every rebuild of the program
// makes a new key, and the old ones would pile up.
constexpr std::size_t kKeep = 4;
constexpr auto kGrace = std::chrono::hours(1);
void prune(const fs::path& folder, const std::string& prefix) {
  std::error_code ec;
  std::vector<std::pair<fs::file_time_type, fs::path>> found;
  const auto now = fs::file_time_type::clock::now();
  for (const auto& e : fs::directory_iterator(folder, ec)) {
    const std::string name = e.path().filename().string();
    if (!e.is_directory(ec)) continue;
    const auto used = fs::last_write_time(e.path(), ec);
    if (name.rfind(prefix, 0) == 0) {
      found.emplace_back(used, e.path());
    } else if (name.rfind("." + prefix, 0) == 0 && name.find(".tmp-") != std::string::npos && now - used > kGrace) {
      fs::remove_all(e.path(), ec);  // left by a run stopped while it simulated
    }
  }
  if (found.size() <= kKeep) return;
  std::sort(found.begin(), found.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  for (std::size_t i = kKeep; i < found.size(); ++i)
    if (now - found[i].first > kGrace) fs::remove_all(found[i].second, ec);
}

}  // namespace

SimulatedSweep simulateSweep(const SimSettings& s, const SweepGrid& grid, const std::string& dir) {
  const auto t0 = Clock::now();
  const SweepSimulator sim(s);
  const std::size_t n = sim.frameCount();
  if (n == 0) throw InputError("sim.sweep: the sweep captured no frames; lengthen it or lower sim.sweep.capture_interval_mm");
  std::error_code made;
  fs::create_directories(dir, made);
  if (made || !fs::is_directory(dir)) throw InputError(dir + ": cannot create the folder for the simulated sweep");
  SimulatedSweep out = pathsIn(s, dir);
  out.frames = n;
  // What each frame must read back as: a hash of its pixels, not the pixels
  // (a 10,000-frame sweep held them all, 1 GiB that the host kept).
  auto hashOf = [](const std::vector<std::uint8_t>& px) {
    return std::hash<std::string_view>{}(std::string_view(reinterpret_cast<const char*>(px.data()), px.size()));
  };
  struct Expected {
    std::uint64_t index;
    double time;
    std::size_t pixelHash;
    Mat4 pose;
  };
  std::vector<Expected> want;
  SequenceWriteOptions wo;
  wo.compress = false;
  wo.fields = {{"UltrasoundImageType", "BRIGHTNESS"}};
  auto writer = SequenceWriter::create(out.sequencePath, wo);
  auto first = SequenceWriter::create(out.firstPath, wo);
  sim.run(s.threads, [&](Frame&& f) {
    want.push_back({f.index, f.timestamp, hashOf(f.pixels), sim.imageToReference(f.index)});
    if (want.size() == 1) first->write(f);
    writer->write(f);
  });
  writer->close();
  first->close();
  writePlusConfig(out.configPath, {{"Image", "Probe", sim.imageToProbe()}}, reconstructionElement(grid(sim)),
                  fmt::format("pp5echo: simulated {} phantom, {} probe, {} sweep, seed {}", enumName(s.phantom),
                              sim.probe().name, enumName(s.sweep.kind), s.seed));

  PosedSequence seq = openPosedSequence(out.sequencePath, out.configPath);
  if (seq.poses.size() != n)
    throw InvariantError(fmt::format("{}: {} frames read back, {} simulated", out.sequencePath, seq.poses.size(), n));
  Frame f;
  for (std::size_t i = 0; i < n; ++i) {
    if (!seq.reader->next(f)) throw InvariantError(fmt::format("{}: frame {} missing", out.sequencePath, i));
    if (!seq.poses[i]) throw InvariantError(fmt::format("{}: frame {} cannot be placed", out.sequencePath, i));
    if (hashOf(f.pixels) != want[i].pixelHash || f.index != want[i].index || f.timestamp != want[i].time)
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

std::string sweepCacheKey(const SimSettings& s) {
  SimSettings copy;
  ConfigSchema schema;
  registerOptions(schema, copy);  // resets copy; the entries read it from here on
  copy = s;
  std::string text = "pp5echo simulated sweep 1\n";
  for (const ConfigSchema::Entry& e : schema.entries())
    if (e.key != "sim.threads") text += e.key + "=" + e.current() + "\n";
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    const auto size = fs::file_size(exe, ec);
    const auto time = fs::last_write_time(exe, ec);
    if (!ec) text += fmt::format("exe={} {} {}\n", exe.string(), size, time.time_since_epoch().count());
  }
  return fmt::format("{:016x}", fnv1a(text));
}

std::string sweepCacheFolder(const std::string& configured) {
  if (!configured.empty()) return configured;
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) return (fs::path(x) / "pp5echo" / "sweeps").string();
  if (const char* h = std::getenv("HOME"); h && *h) return (fs::path(h) / ".cache" / "pp5echo" / "sweeps").string();
  throw InputError("run.sweep_cache: neither XDG_CACHE_HOME nor HOME is set; give the cache folder");
}

SimulatedSweep cachedSweep(const SimSettings& s, const SweepGrid& grid, const std::string& folder) {
  const fs::path dir = fs::path(sweepCacheFolder(folder)) / (stem(s) + "-" + sweepCacheKey(s));
  SimulatedSweep hit = pathsIn(s, dir.string());
  std::error_code ec;
  // A folder under the final name is complete: it is only ever renamed into place.
  if (fs::exists(hit.sequencePath, ec) && fs::exists(hit.configPath, ec)) {
    fs::last_write_time(dir, fs::file_time_type::clock::now(), ec);  // used: kept by prune()
    hit.fromCache = true;
    return hit;
  }
  fs::create_directories(dir.parent_path(), ec);
  if (ec)
    throw InputError(fmt::format("run.sweep_cache: cannot create {}: {}", dir.parent_path().string(), ec.message()));
  // A temporary folder of this run's own (host, process and a random number:
  // runs in different containers may share the cache and a PID), renamed into
  // place once complete.
  char host[256] = "host";
  ::gethostname(host, sizeof host - 1);
  const fs::path tmp = dir.parent_path() / fmt::format(".{}.tmp-{}-{}-{:08x}", dir.filename().string(), host,
                                                       ::getpid(), std::random_device{}());
  spdlog::info("run: simulating the sweep once into {} (later runs with these [sim] settings stream it from there)",
               dir.string());
  SimulatedSweep made = simulateSweep(s, grid, tmp.string());
  fs::rename(tmp, dir, ec);
  if (ec) {
    // Another run put the same sweep there first (the folder is not empty):
    // use that one if it is whole; otherwise say why the rename failed.
    const std::string why = ec.message();
    std::error_code ignore;
    fs::remove_all(tmp, ignore);
    if (fs::exists(hit.sequencePath, ignore) && fs::exists(hit.configPath, ignore)) {
      hit.fromCache = true;
      return hit;
    }
    throw InputError(fmt::format("run.sweep_cache: cannot move the simulated sweep into {}: {}", dir.string(), why));
  }
  prune(dir.parent_path(), stem(s) + "-");
  hit.frames = made.frames;
  hit.maxPoseError = made.maxPoseError;
  hit.simulateS = made.simulateS;
  return hit;
}

}  // namespace pp5::sim
