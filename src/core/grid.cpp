#include "core/grid.hpp"

#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>

#include <unistd.h>

#include "core/error.hpp"

namespace pp5 {

std::uint64_t Grid::memoryBytes(std::uint64_t bytesPerVoxel) const {
  // Saturating product: one PLUS user asked for 397 billion voxels, and the
  // estimate itself must not overflow before we can refuse it.
  constexpr std::uint64_t kMax = std::numeric_limits<std::uint64_t>::max();
  std::uint64_t total = bytesPerVoxel;
  for (int a = 0; a < 3; ++a) {
    const auto d = static_cast<std::uint64_t>(dims[a] < 0 ? 0 : dims[a]);
    if (d != 0 && total > kMax / d) return kMax;
    total *= d;
  }
  return total;
}

std::uint64_t availableMemoryBytes() {
  std::ifstream meminfo("/proc/meminfo");
  std::string line;
  while (std::getline(meminfo, line)) {
    if (line.rfind("MemAvailable:", 0) == 0) {
      std::istringstream is(line.substr(13));
      std::uint64_t kib = 0;
      if (is >> kib) return kib * 1024;
    }
  }
  const long pages = sysconf(_SC_AVPHYS_PAGES);
  const long pageSize = sysconf(_SC_PAGESIZE);
  if (pages > 0 && pageSize > 0) return static_cast<std::uint64_t>(pages) * static_cast<std::uint64_t>(pageSize);
  return std::numeric_limits<std::uint64_t>::max();
}

namespace {
std::string gib(std::uint64_t bytes) {
  return fmt::format("{:.3g} GiB", static_cast<double>(bytes) / (1024.0 * 1024.0 * 1024.0));
}
}  // namespace

void checkGridFits(const Grid& g, std::uint64_t bytesPerVoxel, const std::string& what, std::uint64_t limitBytes) {
  for (int a = 0; a < 3; ++a) {
    if (!(g.spacing[a] > 0.0) || !std::isfinite(g.spacing[a]))
      throw InputError(fmt::format("{}: grid spacing {} {} {} mm must be positive", what, g.spacing.x, g.spacing.y,
                                   g.spacing.z));
    if (!std::isfinite(g.origin[a]))
      throw InputError(fmt::format("{}: grid origin is not finite", what));
    if (g.dims[a] < 1)
      throw InputError(fmt::format("{}: grid of {}x{}x{} voxels has an empty axis", what, g.dims.x, g.dims.y,
                                   g.dims.z));
  }
  const std::uint64_t need = g.memoryBytes(bytesPerVoxel);
  const std::uint64_t have = limitBytes > 0 ? limitBytes : availableMemoryBytes();
  if (need > have)
    throw InputError(fmt::format(
        "{}: a grid of {}x{}x{} voxels ({} bytes per voxel) needs {}, but only {} is available; "
        "use a coarser spacing or a smaller extent",
        what, g.dims.x, g.dims.y, g.dims.z, bytesPerVoxel, gib(need), gib(have)));
}

void checkSameGrid(const Grid& a, const Grid& b) {
  PP5_CHECK_EQ(a.dims.x, b.dims.x);
  PP5_CHECK_EQ(a.dims.y, b.dims.y);
  PP5_CHECK_EQ(a.dims.z, b.dims.z);
  PP5_CHECK(a.origin == b.origin && a.spacing == b.spacing);
}

}  // namespace pp5
