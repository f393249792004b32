#pragma once
// The distributed pipeline's schedules: which rank does what. Pure functions
// with no MPI in them, shared by the host, GP and PP ranks and tested
// exhaustively for small rank counts (tests/test_schedule.cpp).
//
//  - RankLayout: rank 0 the host, ranks 1..G graphics processors (GP), ranks
//    G+1..G+P pixel processors (PP).
//  - TileGrid and tileOwner: the screen cut into square tiles (128 px, a
//    Pixel-Planes 5 renderer, by default), owned by the PPs (and, in the
//    `tile` GP partitioning, by the GPs) contiguously or interleaved.
//  - SlabLayout: the `slab` GP partitioning. The grid's *cells* (dims - 1 per
//    axis: a ray sample belongs to the cell whose 8 voxels it interpolates,
//    gp::stencilCell) are cut into one box per GP, so every lattice sample has
//    exactly one owner. A GP keeps the voxels of its window exact: its cells'
//    voxels plus ghost layers for the gradient and the stencil.
//  - gpsTouched: which GPs a frame (and the fill-in between it and the
//    previous frame) can change, from the reach reconstruction/slice_geometry.hpp bounds.
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "core/grid.hpp"
#include "core/tiles.hpp"
#include "core/transform.hpp"
#include "rendering/dbuffer.hpp"
#include "reconstruction/dirty_region.hpp"
#include "reconstruction/reconstruction.hpp"
#include "core/enum_names.hpp"

namespace pp5::parallel {

enum class Role { Host, Gp, Pp };
const char* roleName(Role r);  // "host" | "GP" | "PP"

struct RankLayout {
  int gps = 1;
  int pps = 1;

  int worldSize() const { return 1 + gps + pps; }
  Role role(int rank) const;            // InvariantError outside 0..worldSize-1
  int gpRank(int g) const { return 1 + g; }          // g in 0..gps-1
  int ppRank(int p) const { return 1 + gps + p; }    // p in 0..pps-1
  int gpIndex(int rank) const { return rank - 1; }
  int ppIndex(int rank) const { return rank - 1 - gps; }

  // The layout for `worldSize` ranks. gps, pps: from the configuration or
  // command line, 0 = derive: P = max(1, size / 4), G = the rest. Throws
  // InputError with a clear sentence when the world is too small (fewer than
  // 3 ranks) or the given counts do not add up to it.
  static RankLayout choose(int worldSize, int gps = 0, int pps = 0);
};

enum class TileOwnership { Contiguous, Interleaved };
TileOwnership tileOwnershipFromName(const std::string& name);  // "contiguous" | "interleaved"; InputError otherwise
const char* tileOwnershipName(TileOwnership o);

// The owner (0..owners-1) of tile `tile` of `count`:
//  contiguous:  floor(tile * owners / count), so each owner holds one run of
//               tiles (row-major) and the run lengths differ by at most one;
//  interleaved: tile mod owners.
int tileOwner(int tile, int count, int owners, TileOwnership o);
// The tiles of `owner`, ascending.
std::vector<int> tilesOwnedBy(int owner, int count, int owners, TileOwnership o);

enum class SlabSplit {
  Longest,  // G slabs along the grid's longest axis
  Grid3d,   // a gx * gy * gz grid of boxes, gx*gy*gz = G, the factors chosen to make the boxes closest to cubes
};
SlabSplit slabSplitFromName(const std::string& name);  // "longest" | "3d"
const char* slabSplitName(SlabSplit s);

class SlabLayout {
public:
  SlabLayout() = default;
  // Cuts the grid's cells (dims - 1 per axis) among `gps` GPs. Cut positions
  // are multiples of `align` cells where the axis has at least `align` cells
  // per part, else of 1 (the last cut is always the axis's end); along an
  // axis cut into n parts, part i < n - 1 ends at round(cells * (i + 1) / n)
  // unaligned, and aligned at ceil(units * (i + 1) / n) alignment units,
  // units = floor(cells / align), so parts differ by at most one alignment
  // unit. A part may be empty when there are more parts than cells. Grid3d
  // numbers the boxes x fastest: g = px + gx * (py + gy * pz).
  SlabLayout(const Grid& grid, int gps, SlabSplit split, int align = 8);

  const Grid& grid() const { return grid_; }
  int gps() const { return static_cast<int>(cells_.size()); }
  // The cells GP g owns (cell c = the voxels c .. c+1 along each axis).
  const gp::Box3& ownedCells(int g) const { return cells_[static_cast<std::size_t>(g)]; }
  // The GP owning cell c (each cell of the grid has exactly one).
  int ownerOfCell(const Index3& c) const;
  // The voxels GP g must keep exact: the voxels of its cells ([lo, hi + 1))
  // grown by `ghostVoxels` on every side, clipped to the grid. Empty when it
  // owns no cell.
  gp::Box3 window(int g, int ghostVoxels) const;
  // The voxels GP g's reconstruction depends on: its window grown as the
  // method needs (gp::reconstructionReach: whole motion-vector cells, the
  // hole filler's reach). Empty when it owns no cell.
  gp::Box3 reach(int g, int ghostVoxels, const gp::ReconSettings& recon) const;
  // The parts per axis (Longest: G along one axis, 1 along the others).
  Index3 parts() const { return parts_; }

private:
  Grid grid_;
  Index3 parts_{1};
  std::vector<std::int64_t> cuts_[3];  // per axis: parts+1 cut positions, in cells
  std::vector<gp::Box3> cells_;
};

// The GPs whose reconstruction a world box (gp::frameReach, gp::fillInReach)
// can change, ascending: those with a voxel of their reach (reaches[g], as
// SlabLayout::reach gives it, worked out once per run) inside the box.
std::vector<int> gpsTouched(const Grid& grid, std::span<const gp::Box3> reaches, const gp::WorldBox& box);

}  // namespace pp5::parallel

namespace pp5 {

template <>
struct EnumNames<parallel::TileOwnership> {
  static constexpr std::string_view key = "parallel.tile_owner";
  static constexpr std::array<std::pair<parallel::TileOwnership, std::string_view>, 2> names{{
      {parallel::TileOwnership::Contiguous, "contiguous"},
      {parallel::TileOwnership::Interleaved, "interleaved"}}};
};

template <>
struct EnumNames<parallel::SlabSplit> {
  static constexpr std::string_view key = "parallel.slab_split";
  static constexpr std::array<std::pair<parallel::SlabSplit, std::string_view>, 2> names{{
      {parallel::SlabSplit::Longest, "longest"},
      {parallel::SlabSplit::Grid3d, "3d"}}};
};

}  // namespace pp5
