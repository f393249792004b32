#include "comm/schedule.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <tuple>

#include <fmt/format.h>
#include <glm/gtc/quaternion.hpp>

#include "core/error.hpp"

namespace pp5::comm {

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
  } else if (pps == 0) {
    if (gps > worldSize - 2)
      throw InputError(fmt::format("parallel.gps = {} needs at least {} ranks (with the host and one pixel "
                                   "processor), but the job has {}",
                                   gps, gps + 2, worldSize));
    l.gps = gps;
    l.pps = worldSize - 1 - gps;
  } else if (gps == 0) {
    if (pps > worldSize - 2)
      throw InputError(fmt::format("parallel.pps = {} needs at least {} ranks (with the host and one graphics "
                                   "processor), but the job has {}",
                                   pps, pps + 2, worldSize));
    l.pps = pps;
    l.gps = worldSize - 1 - pps;
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

TileOwnership tileOwnershipFromName(const std::string& name) {
  if (name == "contiguous") return TileOwnership::Contiguous;
  if (name == "interleaved") return TileOwnership::Interleaved;
  throw InputError(fmt::format("parallel.tile_owner = \"{}\" is not one of contiguous, interleaved", name));
}

const char* tileOwnershipName(TileOwnership o) {
  return o == TileOwnership::Contiguous ? "contiguous" : "interleaved";
}

TileGrid::TileGrid(int w, int h, int ts) : width(w), height(h), tileSize(ts) {
  if (w < 1 || h < 1 || ts < 1)
    throw InputError(fmt::format("a {}x{} pixel image cannot be cut into tiles of {} pixels: every size must be at "
                                 "least 1",
                                 w, h, ts));
}

pp::TileRect TileGrid::rect(int tile) const {
  if (tile < 0 || tile >= count())
    throw InvariantError(fmt::format("tile {} is outside the image's tiles 0..{}", tile, count() - 1));
  const int c = tile % cols(), r = tile / cols();
  pp::TileRect t;
  t.x0 = c * tileSize;
  t.y0 = r * tileSize;
  t.width = std::min(tileSize, width - t.x0);
  t.height = std::min(tileSize, height - t.y0);
  return t;
}

int TileGrid::tileOfPixel(std::uint32_t pixel) const {
  const auto w = static_cast<std::uint32_t>(width);
  if (width < 1 || height < 1 || tileSize < 1 || pixel / w >= static_cast<std::uint32_t>(height))
    throw InvariantError(fmt::format("pixel {} is outside the {}x{} image", pixel, width, height));
  const int x = static_cast<int>(pixel % w), y = static_cast<int>(pixel / w);
  return (y / tileSize) * cols() + x / tileSize;
}

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

std::vector<std::uint64_t> samplesPerTile(const TileGrid& tiles, std::span<const std::uint16_t> counts) {
  const std::size_t n = static_cast<std::size_t>(tiles.width) * static_cast<std::size_t>(tiles.height);
  if (counts.size() != n)
    throw InvariantError(fmt::format("{} sample counts given for a {}x{} image", counts.size(), tiles.width,
                                     tiles.height));
  std::vector<std::uint64_t> sums(static_cast<std::size_t>(tiles.count()), 0);
  const int cols = tiles.cols();
  for (int y = 0; y < tiles.height; ++y) {
    const std::uint16_t* row = counts.data() + static_cast<std::size_t>(y) * static_cast<std::size_t>(tiles.width);
    std::uint64_t* rowSums = sums.data() + static_cast<std::size_t>(y / tiles.tileSize) * static_cast<std::size_t>(cols);
    for (int c = 0; c < cols; ++c) {
      const int x0 = c * tiles.tileSize, x1 = std::min(tiles.width, x0 + tiles.tileSize);
      std::uint64_t s = 0;
      for (int x = x0; x < x1; ++x) s += row[x];
      rowSums[c] += s;
    }
  }
  return sums;
}

// ------------------------------------------------------------------ slabs --

SlabSplit slabSplitFromName(const std::string& name) {
  if (name == "longest") return SlabSplit::Longest;
  if (name == "3d") return SlabSplit::Grid3d;
  throw InputError(fmt::format("parallel.slab_split = \"{}\" is not one of longest, 3d", name));
}

const char* slabSplitName(SlabSplit s) { return s == SlabSplit::Longest ? "longest" : "3d"; }

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

// ------------------------------------------------------------------ reach --
//
// What the tent splat writes (gp/splat_tent.cpp): a slice at pose (origin,
// image axes ex, ey) writes a voxel only when some selected pixel's kernel
// reaches it with a positive weight, i.e. when the voxel lies strictly inside
// pixel + (du u + dv v + dn n) with |du| < hl, |dv| < ha, |dn| < he, where u =
// ex / |ex|, n = ex x ey normalised and v = n x u (SlicePose). Its writes thus
// lie in the Minkowski sum of the selected pixel centres' parallelogram and
// the kernel's oriented box, whose world box is the sum of the two world
// boxes: the parallelogram's corners, and per axis a half-extent hl |u_a| +
// ha |v_a| + he |n_a|. That is the exact hull of the written set (for a
// sheared image it is tighter than the splat's own dirty slab, which bounds
// the pixels by their (u, v) rectangle); kPadMm (as the splat's own dirty
// region adds) and a relative term cover the rounding of the splat's float
// weights and of the arithmetic here.
//
// The selected pixels lie inside the clip rectangle (the fan and rejected
// pixels only remove some), so the rectangle stands for them; a rectangle that
// misses the frame selects nothing, and the splat then takes the whole frame
// for its geometry, as this does.
//
// Other methods than tent do not call these (their callers use the dirty
// region); the functions return the same box for them, built from the tent
// half-widths in `recon`, whatever the method.
//
// The box holds the voxels whose sums a slice changes. With replacement =
// motion_vector a slice also rebases every motion-vector cell it writes to
// (motionVectorBrick voxels a side, aligned to the grid's voxel 0): their
// outputs stay, but their bases and sums change, up to motionVectorBrick - 1
// voxels beyond the box. The box cannot see the grid, so a caller that must
// keep those states exact grows it by that many voxels.
namespace {

constexpr double kPadMm = 1e-3;
constexpr double kRelPad = 1e-9;

struct Axes {
  Vec3 origin, ex, ey;  // pixel (c, r) at origin + c ex + r ey
  Vec3 u, v, n;         // the slice's orthonormal axes
  double sx = 1, eyu = 0, syv = 1;
};

Axes axesOf(const Mat4& m) {
  if (!isFinite(m)) throw InputError("the frame's image-to-reference transform is not finite");
  const double tol = 1e-9;
  if (std::abs(m[0][3]) > tol || std::abs(m[1][3]) > tol || std::abs(m[2][3]) > tol || std::abs(m[3][3] - 1.0) > tol)
    throw InputError("the frame's image-to-reference transform is not affine (last row is not 0 0 0 1)");
  Axes a;
  a.origin = Vec3(m[3]);
  a.ex = Vec3(m[0]);
  a.ey = Vec3(m[1]);
  a.sx = glm::length(a.ex);
  const Vec3 c = glm::cross(a.ex, a.ey);
  const double cl = glm::length(c);
  if (!(a.sx > 1e-12) || !(glm::length(a.ey) > 1e-12) || !(cl > 1e-12 * a.sx * glm::length(a.ey)))
    throw InputError("the frame's image-to-reference transform maps the image's x and y axes onto a line or a point");
  a.u = a.ex / a.sx;
  a.n = c / cl;
  a.v = glm::cross(a.n, a.u);
  a.eyu = glm::dot(a.ey, a.u);
  a.syv = glm::dot(a.ey, a.v);
  return a;
}

// The clip rectangle's pixel centres, inclusive, as gp::pixelRuns clamps it.
struct PixelRect {
  double x0, y0, x1, y1;
};

PixelRect clipRect(int width, int height, const gp::ReconSettings& s) {
  if (width < 1 || height < 1)
    throw InputError(fmt::format("a frame of {}x{} pixels has no pixels to reconstruct", width, height));
  std::int64_t x0 = 0, x1 = width - 1, y0 = 0, y1 = height - 1;
  if (s.clipSize.x > 0 && s.clipSize.y > 0) {
    const std::int64_t cx0 = std::max<std::int64_t>(x0, s.clipOrigin.x);
    const std::int64_t cy0 = std::max<std::int64_t>(y0, s.clipOrigin.y);
    const std::int64_t cx1 = std::min<std::int64_t>(x1, std::int64_t{s.clipOrigin.x} + s.clipSize.x);
    const std::int64_t cy1 = std::min<std::int64_t>(y1, std::int64_t{s.clipOrigin.y} + s.clipSize.y);
    if (cx0 <= cx1 && cy0 <= cy1) {
      x0 = cx0;
      y0 = cy0;
      x1 = cx1;
      y1 = cy1;
    }
  }
  return {static_cast<double>(x0), static_cast<double>(y0), static_cast<double>(x1), static_cast<double>(y1)};
}

std::array<std::array<double, 2>, 4> corners(const PixelRect& r) {
  return {{{r.x0, r.y0}, {r.x1, r.y0}, {r.x0, r.y1}, {r.x1, r.y1}}};
}

gp::WorldBox padded(gp::WorldBox b) {
  for (int a = 0; a < 3; ++a) {
    const double pad = kPadMm + kRelPad * std::max(std::abs(b.lo[a]), std::abs(b.hi[a]));
    b.lo[a] -= pad;
    b.hi[a] += pad;
  }
  return b;
}

// The box around the clipped rectangle's corners (`at` maps a pixel corner to
// world), grown per world axis by the tent kernel along the slice axes u, v, n.
template <typename At>
gp::WorldBox kernelBox(const PixelRect& r, const gp::ReconSettings& s, const Vec3& u, const Vec3& v, const Vec3& n,
                       At at) {
  gp::WorldBox b{Vec3(std::numeric_limits<double>::infinity()), Vec3(-std::numeric_limits<double>::infinity())};
  for (const auto& [c, y] : corners(r)) {
    const Vec3 w = at(c, y);
    b.lo = glm::min(b.lo, w);
    b.hi = glm::max(b.hi, w);
  }
  const Vec3 k = s.kernelLateralMm * glm::abs(u) + s.kernelAxialMm * glm::abs(v) + s.kernelElevationMm * glm::abs(n);
  b.lo -= k;
  b.hi += k;
  return b;
}

// The exact reach, unpadded.
gp::WorldBox reachOf(const Axes& p, const PixelRect& r, const gp::ReconSettings& s) {
  return kernelBox(r, s, p.u, p.v, p.n, [&](double c, double y) { return p.origin + c * p.ex + y * p.ey; });
}

}  // namespace

gp::WorldBox frameReach(const Mat4& imageToReference, int width, int height, const gp::ReconSettings& recon) {
  return padded(reachOf(axesOf(imageToReference), clipRect(width, height, recon), recon));
}

// The fill-in slices (gp/splat_tent.cpp, interpolatePose) between poses a
// and b: at t in (0, 1), origin o(t) = lerp(o_a, o_b, t), rotation R(t) =
// R_a E(t theta), E the rotation by the angle theta between the frames about
// a fixed axis w (in a's axes), and pixel steps (sx, eyu, syv) linear in t.
// The reconstructor picks their number and t from the pixels it selects,
// which this cannot know, so the box holds the slices for every t.
//
// It is the union of the reaches of the slices at t_j = j / N (t_0 and t_N the
// frames themselves), N = ceil(theta / 1 degree), grown by what the path can
// bulge between two of them. Between t_j and t_j+1 the path is again of this
// form (origin linear, a slerp by theta / N about w, steps linear), so a point
// the slice at t writes is o(t) + R(t) p(t), with p(t) = lerp(p_j, p_j+1, s) + k
// in slice coordinates (a pixel, moved linearly, plus a kernel offset k), and
//     o(t) + R(t) p(t) = lerp(o_j + R_j p_j', o_j+1 + R_j+1 p_j+1', s)
//                        + (1 - s) d_j + s d_j+1 + s (1 - s) (R_j+1 - R_j)(p_j' - p_j+1'),
// with p' = p + k and d = R(t) p' - lerp(R_j p', R_j+1 p', s) the gap between
// the arc that p' sweeps at constant angular speed and its chord at the same
// s. The first term is a convex combination of points of the two slices'
// reaches, so it lies in the union's box. On a circle of radius rho and
// half-angle a = theta / (2N) the gap is at most rho (1 - cos a) across the
// chord (the sagitta) plus rho (a - sin a) along it; and |(R_j+1 - R_j) x| <=
// 2 sin(a) |x|, where |p_j - p_j+1| <= dMax / N. Every term is perpendicular to
// w, so along world axis i the growth is their sum times sqrt(1 - w_i^2). rho
// is the largest distance from the axis over the vertices of either frame's
// pixel rectangle plus kernel box: the distance is convex in p, and p(t) is
// linear in t. With 1 degree steps the growth is below 4e-5 rho (5 um for a
// 120 mm deep image), where growing the two frames' union once by the whole
// rotation's sagitta would add 1.3 % of rho on both sides of every axis
// across the rotation.
namespace {

struct SliceAxes {
  Vec3 origin, u, v, n;
  double sx, eyu, syv;
};

gp::WorldBox sliceReach(const SliceAxes& p, const PixelRect& r, const gp::ReconSettings& s) {
  return kernelBox(r, s, p.u, p.v, p.n,
                   [&](double c, double y) { return p.origin + (c * p.sx + y * p.eyu) * p.u + (y * p.syv) * p.v; });
}

}  // namespace

gp::WorldBox fillInReach(const Mat4& previous, const Mat4& current, int width, int height,
                         const gp::ReconSettings& recon) {
  const Axes a = axesOf(previous), b = axesOf(current);
  const PixelRect r = clipRect(width, height, recon);
  gp::WorldBox box = reachOf(a, r, recon);
  const gp::WorldBox rb = reachOf(b, r, recon);
  box.lo = glm::min(box.lo, rb.lo);
  box.hi = glm::max(box.hi, rb.hi);

  // The rotation between them, as interpolatePose takes it.
  using Quat = glm::dquat;
  const Quat qa = glm::normalize(glm::quat_cast(glm::dmat3(a.u, a.v, a.n)));
  Quat qb = glm::normalize(glm::quat_cast(glm::dmat3(b.u, b.v, b.n)));
  if (glm::dot(qa, qb) < 0.0) qb = -qb;
  const Quat rel = glm::conjugate(qa) * qb;  // qb = qa * rel
  const double theta = 2.0 * std::acos(std::min(1.0, std::abs(rel.w)));
  // No slice is filled in without fill-in, or across a rotation the
  // reconstructor treats as a jump (the small margin keeps the decision on the
  // safe side of its rounding).
  constexpr double kDegPerRad = 180.0 / 3.14159265358979323846;
  if (!recon.fillIn || theta * kDegPerRad > recon.fillInMaxAngleDeg + 1e-6) return padded(box);

  const int steps = std::clamp(static_cast<int>(std::ceil(theta * kDegPerRad)), 1, 180);
  for (int j = 1; j < steps; ++j) {
    const double t = static_cast<double>(j) / steps;
    const glm::dmat3 m = glm::mat3_cast(glm::normalize(glm::slerp(qa, qb, t)));
    const SliceAxes p{a.origin + (b.origin - a.origin) * t, m[0], m[1], m[2], a.sx + (b.sx - a.sx) * t,
                      a.eyu + (b.eyu - a.eyu) * t, a.syv + (b.syv - a.syv) * t};
    const gp::WorldBox pb = sliceReach(p, r, recon);
    box.lo = glm::min(box.lo, pb.lo);
    box.hi = glm::max(box.hi, pb.hi);
  }

  const Vec3 im(rel.x, rel.y, rel.z);
  const double iml = glm::length(im);
  const bool haveAxis = iml > 1e-12;
  const Vec3 w = haveAxis ? im / iml : Vec3(0.0);  // in a's (u, v, n) axes
  auto distFromAxis = [&](const Vec3& p) { return haveAxis ? glm::length(p - glm::dot(p, w) * w) : glm::length(p); };
  double rho = 0.0, dMax = 0.0;
  const double hl = recon.kernelLateralMm, ha = recon.kernelAxialMm, he = recon.kernelElevationMm;
  for (const auto& [c, y] : corners(r)) {
    const Vec3 pa(c * a.sx + y * a.eyu, y * a.syv, 0.0), pb(c * b.sx + y * b.eyu, y * b.syv, 0.0);
    dMax = std::max(dMax, distFromAxis(pa - pb));
    for (int k = 0; k < 8; ++k) {
      const Vec3 kk((k & 1) ? hl : -hl, (k & 2) ? ha : -ha, (k & 4) ? he : -he);
      rho = std::max({rho, distFromAxis(pa + kk), distFromAxis(pb + kk)});
    }
  }
  const double half = 0.5 * theta / steps;
  const double grow =
      rho * ((1.0 - std::cos(half)) + (half - std::sin(half))) + 0.5 * std::sin(half) * dMax / steps;
  const Vec3 wWorld = haveAxis ? glm::dmat3(a.u, a.v, a.n) * w : Vec3(0.0);
  for (int i = 0; i < 3; ++i) {
    const double g = grow * (haveAxis ? std::sqrt(std::max(0.0, 1.0 - wWorld[i] * wWorld[i])) : 1.0);
    box.lo[i] -= g;
    box.hi[i] += g;
  }
  return padded(box);
}

std::vector<int> gpsTouched(const SlabLayout& slabs, const gp::WorldBox& box, int ghostVoxels) {
  std::vector<int> out;
  for (int a = 0; a < 3; ++a)
    if (!(box.lo[a] <= box.hi[a])) return out;  // empty or NaN
  const Grid& g = slabs.grid();
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
  for (int k = 0; k < slabs.gps(); ++k) {
    const gp::Box3 w = slabs.window(k, ghostVoxels);
    if (w.empty()) continue;
    bool hit = true;
    for (int a = 0; a < 3 && hit; ++a)
      hit = w.lo[a] <= last[static_cast<std::size_t>(a)] && first[static_cast<std::size_t>(a)] < w.hi[a];
    if (hit) out.push_back(k);
  }
  return out;
}

}  // namespace pp5::comm
