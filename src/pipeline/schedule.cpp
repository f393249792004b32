#include "pipeline/schedule.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <tuple>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::parallel {

// ------------------------------------------------------------------ ranks --

const char* roleName(Role r) {
  switch (r) {
    case Role::Host: return "host";
    case Role::Gp: return "GP";
    case Role::Pp: return "PP";
  }
  return "?";
}

Role RankLayout::role(int rank) const {
  if (rank < 0 || rank >= worldSize())
    throw InvariantError(fmt::format("rank {} is outside the job's ranks 0..{}", rank, worldSize() - 1));
  if (rank == 0) return Role::Host;
  return rank <= gps ? Role::Gp : Role::Pp;
}

RankLayout RankLayout::choose(int worldSize, int gps, int pps) {
  if (worldSize < 3)
    throw InputError(fmt::format("the job has {} rank{}; pp5echo needs at least 3: one host, one graphics "
                                 "processor, one pixel processor",
                                 worldSize, worldSize == 1 ? "" : "s"));
  if (gps < 0) throw InputError(fmt::format("parallel.gps = {} is negative; give 0 to derive it from the job size", gps));
  if (pps < 0) throw InputError(fmt::format("parallel.pps = {} is negative; give 0 to derive it from the job size", pps));
  RankLayout l;
  if (gps == 0 && pps == 0) {
    l.pps = std::max(1, worldSize / 4);
    l.gps = worldSize - 1 - l.pps;  // >= 1 for worldSize >= 3
  } else if (gps == 0 || pps == 0) {
    // One kind given: the other takes the ranks left.
    const bool gpsGiven = pps == 0;
    const int n = gpsGiven ? gps : pps;
    if (n > worldSize - 2)
      throw InputError(fmt::format("parallel.{} = {} needs at least {} ranks (with the host and one {} "
                                   "processor), but the job has {}",
                                   gpsGiven ? "gps" : "pps", n, n + 2, gpsGiven ? "pixel" : "graphics", worldSize));
    (gpsGiven ? l.gps : l.pps) = n;
    (gpsGiven ? l.pps : l.gps) = worldSize - 1 - n;
  } else {
    if (static_cast<long long>(gps) + pps + 1 != worldSize)
      throw InputError(fmt::format("parallel.gps = {} and parallel.pps = {} need {} ranks, but the job has {}", gps,
                                   pps, static_cast<long long>(gps) + pps + 1, worldSize));
    l.gps = gps;
    l.pps = pps;
  }
  return l;
}

// ------------------------------------------------------------------ tiles --

TileOwnership tileOwnershipFromName(const std::string& name) { return enumFromName<TileOwnership>(name); }

const char* tileOwnershipName(TileOwnership o) { return enumName(o).data(); }

namespace {
void checkTileArgs(int tile, int count, int owners) {
  if (count < 1 || owners < 1 || tile < 0 || tile >= count)
    throw InvariantError(fmt::format("tile {} of {} among {} owners is not a valid tile", tile, count, owners));
}
}  // namespace

int tileOwner(int tile, int count, int owners, TileOwnership o) {
  checkTileArgs(tile, count, owners);
  if (o == TileOwnership::Interleaved) return tile % owners;
  return static_cast<int>(static_cast<std::int64_t>(tile) * owners / count);
}

std::vector<int> tilesOwnedBy(int owner, int count, int owners, TileOwnership o) {
  if (count < 1 || owners < 1 || owner < 0 || owner >= owners)
    throw InvariantError(fmt::format("owner {} of {} (for {} tiles) is not a valid owner", owner, owners, count));
  std::vector<int> tiles;
  if (o == TileOwnership::Interleaved) {
    for (int t = owner; t < count; t += owners) tiles.push_back(t);
    return tiles;
  }
  // floor(t * owners / count) == owner  <=>  ceil(owner * count / owners) <= t < ceil((owner+1) * count / owners)
  const auto first = [&](std::int64_t j) { return static_cast<int>((j * count + owners - 1) / owners); };
  for (int t = first(owner); t < first(owner + 1); ++t) tiles.push_back(t);
  return tiles;
}


// ------------------------------------------------------------------ slabs --

SlabSplit slabSplitFromName(const std::string& name) { return enumFromName<SlabSplit>(name); }

const char* slabSplitName(SlabSplit s) { return enumName(s).data(); }

namespace {

// round(a / b) for a >= 0, b > 0, halves up.
std::int64_t roundDiv(std::int64_t a, std::int64_t b) { return (2 * a + b) / (2 * b); }

// parts + 1 cut positions along an axis of `cells` cells (see the header).
// Unaligned, part i ends at round(cells (i + 1) / parts). Aligned, the
// cells' whole units of `align` are dealt out with ceil(units (i + 1) /
// parts) and the last part also takes the cells past the last whole unit:
// rounding each end to the nearest unit instead can give the last part one
// unit more than another part plus that remainder (5 cells, 2 parts, units
// of 2: 4 and 1), while with ceil the last part holds the fewest units, so
// no two parts differ by more than one unit.
std::vector<std::int64_t> axisCuts(std::int64_t cells, std::int64_t parts, std::int64_t align) {
  std::vector<std::int64_t> cuts(static_cast<std::size_t>(parts + 1), 0);
  const bool aligned = align > 1 && cells >= align * parts;
  const std::int64_t units = cells / align;
  for (std::int64_t i = 0; i + 1 < parts; ++i)
    cuts[static_cast<std::size_t>(i + 1)] =
        aligned ? (units * (i + 1) + parts - 1) / parts * align : roundDiv(cells * (i + 1), parts);
  cuts[static_cast<std::size_t>(parts)] = cells;
  return cuts;
}

// The factors gx * gy * gz = G that make the boxes closest to cubes: the least
// total box surface, sum over boxes of 2 (bx by + by bz + bz bx) with b = n / g,
// which is 2 (ny nz gx + nz nx gy + nx ny gz). Factorisations that leave no
// part without cells are preferred to those that do (an empty part is an idle
// GP); ties go to more parts along z, then along y, the slow axes of the
// volume's memory, so a box's voxels lie in fewer, longer runs.
Index3 grid3dFactors(const Index3& n, std::int64_t G) {
  using Key = std::tuple<int, std::int64_t, std::int64_t, std::int64_t>;  // (empty parts, cost, -gz, -gy)
  Key best{std::numeric_limits<int>::max(), 0, 0, 0};
  Index3 bestF(1, 1, G);
  for (std::int64_t gx = 1; gx <= G; ++gx) {
    if (G % gx) continue;
    for (std::int64_t gy = 1; gy <= G / gx; ++gy) {
      if ((G / gx) % gy) continue;
      const std::int64_t gz = G / gx / gy;
      const int empty = (gx > n.x) + (gy > n.y) + (gz > n.z);
      const std::int64_t cost = n.y * n.z * gx + n.z * n.x * gy + n.x * n.y * gz;
      const Key k{empty > 0 ? 1 : 0, cost, -gz, -gy};
      if (k < best) {
        best = k;
        bestF = Index3(gx, gy, gz);
      }
    }
  }
  return bestF;
}

}  // namespace

SlabLayout::SlabLayout(const Grid& grid, int gps, SlabSplit split, int align) : grid_(grid) {
  if (gps < 1) throw InvariantError(fmt::format("a slab layout needs at least one GP, got {}", gps));
  if (align < 1) throw InvariantError(fmt::format("a slab layout needs an alignment of at least 1, got {}", align));
  const Index3 n = glm::max(grid.dims - Index3(1), Index3(0));
  if (split == SlabSplit::Longest) {
    // The axis with the most cells; ties go to z, then y: slabs along the
    // slowest axis are contiguous in memory.
    int axis = 2;
    for (int a = 1; a >= 0; --a)
      if (n[a] > n[axis]) axis = a;
    parts_ = Index3(1);
    parts_[axis] = gps;
  } else {
    parts_ = grid3dFactors(n, gps);
  }
  for (int a = 0; a < 3; ++a) cuts_[a] = axisCuts(n[a], parts_[a], align);
  cells_.resize(static_cast<std::size_t>(gps));
  for (std::int64_t pz = 0; pz < parts_.z; ++pz)
    for (std::int64_t py = 0; py < parts_.y; ++py)
      for (std::int64_t px = 0; px < parts_.x; ++px) {
        const auto g = static_cast<std::size_t>(px + parts_.x * (py + parts_.y * pz));
        const Index3 p(px, py, pz);
        gp::Box3 b;
        for (int a = 0; a < 3; ++a) {
          b.lo[a] = cuts_[a][static_cast<std::size_t>(p[a])];
          b.hi[a] = cuts_[a][static_cast<std::size_t>(p[a] + 1)];
        }
        cells_[g] = b;
      }
}

int SlabLayout::ownerOfCell(const Index3& c) const {
  Index3 p;
  for (int a = 0; a < 3; ++a) {
    const auto& cuts = cuts_[a];
    if (cuts.empty() || c[a] < 0 || c[a] >= cuts.back())
      throw InvariantError(fmt::format("cell ({}, {}, {}) is outside the grid's {}x{}x{} cells", c.x, c.y, c.z,
                                       cuts_[0].empty() ? 0 : cuts_[0].back(), cuts_[1].empty() ? 0 : cuts_[1].back(),
                                       cuts_[2].empty() ? 0 : cuts_[2].back()));
    // The last part starting at or before c: empty parts (equal cuts) are skipped.
    p[a] = std::upper_bound(cuts.begin(), cuts.end(), c[a]) - cuts.begin() - 1;
  }
  return static_cast<int>(p.x + parts_.x * (p.y + parts_.y * p.z));
}

gp::Box3 SlabLayout::window(int g, int ghostVoxels) const {
  const gp::Box3& c = ownedCells(g);
  if (c.empty()) return {};
  const gp::Box3 voxels{c.lo, c.hi + Index3(1)};
  return voxels.grown(std::max(0, ghostVoxels)).intersect({Index3(0), grid_.dims});
}

gp::Box3 SlabLayout::reach(int g, int ghostVoxels, const gp::ReconSettings& recon) const {
  const gp::Box3 w = window(g, ghostVoxels);
  return w.empty() ? w : gp::reconstructionReach(grid_, recon, w);
}

std::vector<int> gpsTouched(const Grid& grid, std::span<const gp::Box3> reaches, const gp::WorldBox& box) {
  std::vector<int> out;
  for (int a = 0; a < 3; ++a)
    if (!(box.lo[a] <= box.hi[a])) return out;  // empty or NaN
  const Grid& g = grid;
  // Per axis, the voxel indices whose world position (as Grid::voxelToWorld
  // computes it) lies in [lo, hi]: a contiguous range, since the position is
  // monotone in the index. A guess from the division, widened by one, is
  // trimmed by testing the positions themselves.
  std::array<std::int64_t, 3> first{}, last{};
  for (int a = 0; a < 3; ++a) {
    const double o = g.origin[a], s = g.spacing[a];
    const auto n = static_cast<double>(g.dims[a]);
    auto pos = [&](std::int64_t i) { return o + static_cast<double>(i) * s; };
    double f0 = (box.lo[a] - o) / s, f1 = (box.hi[a] - o) / s;
    if (f0 > f1) std::swap(f0, f1);
    if (!(f0 == f0) || !(f1 == f1)) return out;
    std::int64_t i0 = static_cast<std::int64_t>(std::floor(std::clamp(f0, -2.0, n + 1.0))) - 1;
    std::int64_t i1 = static_cast<std::int64_t>(std::ceil(std::clamp(f1, -2.0, n + 1.0))) + 1;
    i0 = std::max<std::int64_t>(i0, 0);
    i1 = std::min<std::int64_t>(i1, g.dims[a] - 1);
    auto inside = [&](std::int64_t i) { return pos(i) >= box.lo[a] && pos(i) <= box.hi[a]; };
    while (i0 <= i1 && !inside(i0)) ++i0;
    while (i1 >= i0 && !inside(i1)) --i1;
    if (i0 > i1) return out;
    first[static_cast<std::size_t>(a)] = i0;
    last[static_cast<std::size_t>(a)] = i1;
  }
  for (int k = 0; k < static_cast<int>(reaches.size()); ++k) {
    const gp::Box3& w = reaches[static_cast<std::size_t>(k)];
    if (w.empty()) continue;
    bool hit = true;
    for (int a = 0; a < 3 && hit; ++a)
      hit = w.lo[a] <= last[static_cast<std::size_t>(a)] && first[static_cast<std::size_t>(a)] < w.hi[a];
    if (hit) out.push_back(k);
  }
  return out;
}

}  // namespace pp5::parallel
