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
//  - frameReach / fillInReach / gpsTouched: which GPs a frame (and the fill-in
//    between it and the previous frame) can change.
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "core/grid.hpp"
#include "core/transform.hpp"
#include "gp/dbuffer.hpp"
#include "gp/dirty_region.hpp"
#include "gp/reconstruction.hpp"
#include "pp/ray_cache.hpp"

namespace pp5::comm {

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

// The image cut into tiles of tileSize x tileSize pixels, row-major, the last
// column and row cut short.
struct TileGrid {
  int width = 0, height = 0, tileSize = 128;

  TileGrid() = default;
  TileGrid(int width, int height, int tileSize);  // InputError for sizes < 1
  int cols() const { return (width + tileSize - 1) / tileSize; }
  int rows() const { return (height + tileSize - 1) / tileSize; }
  int count() const { return cols() * rows(); }
  pp::TileRect rect(int tile) const;
  int tileOfPixel(std::uint32_t pixel) const;  // pixel = y * width + x
};

// The owner (0..owners-1) of tile `tile` of `count`:
//  contiguous:  floor(tile * owners / count), so each owner holds one run of
//               tiles (row-major) and the run lengths differ by at most one;
//  interleaved: tile mod owners.
int tileOwner(int tile, int count, int owners, TileOwnership o);
// The tiles of `owner`, ascending.
std::vector<int> tilesOwnedBy(int owner, int count, int owners, TileOwnership o);

// The lattice samples of each tile: the sum of its pixels' sample counts
// (SampleLattice::counts(), row-major over the image), the size of its ray cache.
std::vector<std::uint64_t> samplesPerTile(const TileGrid& tiles, std::span<const std::uint16_t> counts);

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
  // The parts per axis (Longest: G along one axis, 1 along the others).
  Index3 parts() const { return parts_; }

private:
  Grid grid_;
  Index3 parts_{1};
  std::vector<std::int64_t> cuts_[3];  // per axis: parts+1 cut positions, in cells
  std::vector<gp::Box3> cells_;
};

// The world box around every voxel that inserting a frame of width x height
// pixels at `imageToReference` can change with the tent kernel of `recon`:
// the clip rectangle's pixel centres (the whole frame when none is set)
// grown by the kernel's half-widths along the slice's own axes, then boxed in
// world axes.
gp::WorldBox frameReach(const Mat4& imageToReference, int width, int height, const gp::ReconSettings& recon);
// The same for the fill-in slices between two consecutive frames (poses
// interpolated by slerp), whatever their number, with both frames' reaches:
// the union of the reaches of both frames and of interpolated slices at most
// 1 degree of rotation apart, grown by the sagitta of the rotation between
// neighbours over the frame's largest radius. Just the two frames' union when
// recon.fillIn is off or the rotation exceeds recon.fillInMaxAngleDeg (a jump:
// nothing is filled in).
gp::WorldBox fillInReach(const Mat4& previous, const Mat4& current, int width, int height,
                         const gp::ReconSettings& recon);
// The GPs whose windows (ghostVoxels) a world box touches, ascending.
std::vector<int> gpsTouched(const SlabLayout& slabs, const gp::WorldBox& box, int ghostVoxels);

}  // namespace pp5::comm
