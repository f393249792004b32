// The distributed pipeline's schedules (pipeline/schedule.hpp), tested
// exhaustively for small counts (1..16 ranks, owners and GPs, odd and prime
// ones included) against brute-force loops.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <numeric>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <glm/gtc/quaternion.hpp>

#include "pipeline/schedule.hpp"
#include "core/camera.hpp"
#include "core/error.hpp"
#include "core/frame.hpp"
#include "core/grid.hpp"
#include "core/render_settings.hpp"
#include "formats/volume_io.hpp"
#include "rendering/ray_sampler.hpp"
#include "reconstruction/reconstruction.hpp"
#include "core/sample_lattice.hpp"
#include "reconstruction/slice_geometry.hpp"
#include "reconstruction/splat_tent.hpp"

namespace {

using pp5::Grid;
using pp5::Index3;
using pp5::InputError;
using pp5::InvariantError;
using pp5::Mat4;
using pp5::Vec3;
using pp5::parallel::RankLayout;
using pp5::parallel::Role;
using pp5::parallel::SlabLayout;
using pp5::parallel::SlabSplit;
using pp5::TileGrid;
using pp5::parallel::TileOwnership;
using pp5::gp::Box3;
using pp5::gp::ReconSettings;
using pp5::gp::WorldBox;

std::string inputErrorMessage(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "(no InputError)";
}

// ------------------------------------------------------------------ ranks --

TEST(RankLayout, ChooseForEveryWorldSizeAndCount) {
  int valid = 0;
  for (int world = 1; world <= 16; ++world)
    for (int g = 0; g <= 17; ++g)
      for (int p = 0; p <= 17; ++p) {
        SCOPED_TRACE(testing::Message() << "world " << world << " gps " << g << " pps " << p);
        bool ok = world >= 3;
        if (ok) {
          if (g > 0 && p > 0) ok = g + p + 1 == world;
          else if (g > 0) ok = g <= world - 2;
          else if (p > 0) ok = p <= world - 2;
        }
        if (!ok) {
          EXPECT_THROW(RankLayout::choose(world, g, p), InputError);
          continue;
        }
        ++valid;
        const RankLayout l = RankLayout::choose(world, g, p);
        EXPECT_EQ(l.worldSize(), world);
        EXPECT_GE(l.gps, 1);
        EXPECT_GE(l.pps, 1);
        if (g > 0) { EXPECT_EQ(l.gps, g); }
        if (p > 0) { EXPECT_EQ(l.pps, p); }
        if (g == 0 && p == 0) { EXPECT_EQ(l.pps, std::max(1, world / 4)); }
        // The roles partition the ranks: host 0, then the GPs, then the PPs.
        int hosts = 0, gps = 0, pps = 0;
        for (int r = 0; r < world; ++r) {
          const Role role = l.role(r);
          if (role == Role::Host) {
            ++hosts;
            EXPECT_EQ(r, 0);
          } else if (role == Role::Gp) {
            EXPECT_EQ(l.gpIndex(r), gps);
            EXPECT_EQ(l.gpRank(l.gpIndex(r)), r);
            ++gps;
          } else {
            EXPECT_EQ(gps, l.gps) << "a PP before the last GP";
            EXPECT_EQ(l.ppIndex(r), pps);
            EXPECT_EQ(l.ppRank(l.ppIndex(r)), r);
            ++pps;
          }
        }
        EXPECT_EQ(hosts, 1);
        EXPECT_EQ(gps, l.gps);
        EXPECT_EQ(pps, l.pps);
        for (int i = 0; i < l.gps; ++i) EXPECT_EQ(l.role(l.gpRank(i)), Role::Gp);
        for (int i = 0; i < l.pps; ++i) EXPECT_EQ(l.role(l.ppRank(i)), Role::Pp);
        EXPECT_THROW(l.role(-1), InvariantError);
        EXPECT_THROW(l.role(world), InvariantError);
      }
  EXPECT_GT(valid, 100);
}

TEST(RankLayout, ErrorsAreOneSentenceNamingTheOption) {
  EXPECT_EQ(inputErrorMessage([] { RankLayout::choose(6, 5, 2); }),
            "parallel.gps = 5 and parallel.pps = 2 need 8 ranks, but the job has 6");
  EXPECT_EQ(inputErrorMessage([] { RankLayout::choose(2); }),
            "the job has 2 ranks; pp5echo needs at least 3: one host, one graphics processor, one pixel processor");
  EXPECT_NE(inputErrorMessage([] { RankLayout::choose(6, 5); }).find("parallel.gps = 5"), std::string::npos);
  EXPECT_NE(inputErrorMessage([] { RankLayout::choose(6, 0, 5); }).find("parallel.pps = 5"), std::string::npos);
  EXPECT_NE(inputErrorMessage([] { RankLayout::choose(6, -1); }).find("parallel.gps"), std::string::npos);
  EXPECT_NE(inputErrorMessage([] { RankLayout::choose(6, 0, -2); }).find("parallel.pps"), std::string::npos);
  EXPECT_STREQ(pp5::parallel::roleName(Role::Host), "host");
  EXPECT_STREQ(pp5::parallel::roleName(Role::Gp), "GP");
  EXPECT_STREQ(pp5::parallel::roleName(Role::Pp), "PP");
}

// ------------------------------------------------------------------ tiles --

TEST(TileOwner, ContiguousRunsAreInOrderAndBalanced) {
  for (int count = 1; count <= 40; ++count)
    for (int owners = 1; owners <= 16; ++owners) {
      SCOPED_TRACE(testing::Message() << count << " tiles, " << owners << " owners");
      std::vector<int> runLength(static_cast<std::size_t>(owners), 0);
      int prev = 0;
      for (int t = 0; t < count; ++t) {
        const int o = pp5::parallel::tileOwner(t, count, owners, TileOwnership::Contiguous);
        ASSERT_GE(o, 0);
        ASSERT_LT(o, owners);
        ASSERT_GE(o, prev) << "owners out of order at tile " << t;  // so each owner holds one run
        EXPECT_EQ(o, t * owners / count);
        prev = o;
        ++runLength[static_cast<std::size_t>(o)];
      }
      const auto [mn, mx] = std::minmax_element(runLength.begin(), runLength.end());
      EXPECT_LE(*mx - *mn, 1);
      std::vector<int> seen(static_cast<std::size_t>(count), 0);
      for (int o = 0; o < owners; ++o) {
        const std::vector<int> tiles = pp5::parallel::tilesOwnedBy(o, count, owners, TileOwnership::Contiguous);
        EXPECT_EQ(static_cast<int>(tiles.size()), runLength[static_cast<std::size_t>(o)]);
        for (std::size_t i = 0; i < tiles.size(); ++i) {
          if (i > 0) { EXPECT_EQ(tiles[i], tiles[i - 1] + 1) << "not one run"; }
          EXPECT_EQ(pp5::parallel::tileOwner(tiles[i], count, owners, TileOwnership::Contiguous), o);
          ++seen[static_cast<std::size_t>(tiles[i])];
        }
      }
      for (int t = 0; t < count; ++t) EXPECT_EQ(seen[static_cast<std::size_t>(t)], 1) << "tile " << t;
    }
}

TEST(TileOwner, InterleavedIsTileModOwners) {
  for (int count = 1; count <= 40; ++count)
    for (int owners = 1; owners <= 16; ++owners) {
      SCOPED_TRACE(testing::Message() << count << " tiles, " << owners << " owners");
      std::vector<int> seen(static_cast<std::size_t>(count), 0);
      for (int t = 0; t < count; ++t) EXPECT_EQ(pp5::parallel::tileOwner(t, count, owners, TileOwnership::Interleaved), t % owners);
      for (int o = 0; o < owners; ++o) {
        const std::vector<int> tiles = pp5::parallel::tilesOwnedBy(o, count, owners, TileOwnership::Interleaved);
        EXPECT_TRUE(std::is_sorted(tiles.begin(), tiles.end()));
        EXPECT_EQ(static_cast<int>(tiles.size()), count / owners + (o < count % owners ? 1 : 0));
        for (const int t : tiles) {
          EXPECT_EQ(pp5::parallel::tileOwner(t, count, owners, TileOwnership::Interleaved), o);
          ++seen[static_cast<std::size_t>(t)];
        }
      }
      for (int t = 0; t < count; ++t) EXPECT_EQ(seen[static_cast<std::size_t>(t)], 1) << "tile " << t;
    }
}

TEST(TileOwner, NamesAndInvalidArguments) {
  for (const TileOwnership o : {TileOwnership::Contiguous, TileOwnership::Interleaved}) {
    EXPECT_EQ(pp5::parallel::tileOwnershipFromName(pp5::parallel::tileOwnershipName(o)), o);
    EXPECT_THROW(pp5::parallel::tileOwner(5, 5, 2, o), InvariantError);
    EXPECT_THROW(pp5::parallel::tileOwner(-1, 5, 2, o), InvariantError);
    EXPECT_THROW(pp5::parallel::tileOwner(0, 5, 0, o), InvariantError);
    EXPECT_THROW(pp5::parallel::tilesOwnedBy(2, 5, 2, o), InvariantError);
  }
  EXPECT_EQ(inputErrorMessage([] { pp5::parallel::tileOwnershipFromName("striped"); }),
            "parallel.tile_owner = \"striped\" is not one of contiguous, interleaved");
}

TEST(TileGrid, RectsCoverTheImageExactlyOnce) {
  int grids = 0;
  for (const int ts : {1, 2, 3, 5, 7, 8, 16, 31, 128})
    for (int w = 1; w <= 70; w += (w < 20 ? 1 : 7))
      for (int h = 1; h <= 70; h += (h < 20 ? 1 : 9)) {
        SCOPED_TRACE(testing::Message() << w << "x" << h << " in tiles of " << ts);
        const TileGrid tg(w, h, ts);
        ++grids;
        ASSERT_EQ(tg.cols(), (w + ts - 1) / ts);
        ASSERT_EQ(tg.rows(), (h + ts - 1) / ts);
        std::vector<int> owner(static_cast<std::size_t>(w * h), -1);
        for (int t = 0; t < tg.count(); ++t) {
          const pp5::TileRect r = tg.rect(t);
          ASSERT_FALSE(r.empty());
          ASSERT_GE(r.x0, 0);
          ASSERT_GE(r.y0, 0);
          ASSERT_LE(r.x0 + r.width, w);
          ASSERT_LE(r.y0 + r.height, h);
          ASSERT_LE(r.width, ts);
          ASSERT_LE(r.height, ts);
          // Row-major, square except in the last column and row.
          EXPECT_EQ(r.x0, (t % tg.cols()) * ts);
          EXPECT_EQ(r.y0, (t / tg.cols()) * ts);
          if (t % tg.cols() + 1 < tg.cols()) { EXPECT_EQ(r.width, ts); }
          if (t / tg.cols() + 1 < tg.rows()) { EXPECT_EQ(r.height, ts); }
          for (int y = r.y0; y < r.y0 + r.height; ++y)
            for (int x = r.x0; x < r.x0 + r.width; ++x) {
              int& o = owner[static_cast<std::size_t>(y * w + x)];
              ASSERT_EQ(o, -1) << "pixel " << x << "," << y << " in two tiles";
              o = t;
            }
        }
        for (int p = 0; p < w * h; ++p) {
          ASSERT_NE(owner[static_cast<std::size_t>(p)], -1) << "pixel " << p << " in no tile";
          ASSERT_EQ(tg.tileOfPixel(static_cast<std::uint32_t>(p)), owner[static_cast<std::size_t>(p)]);
        }
        EXPECT_THROW(tg.rect(tg.count()), InvariantError);
        EXPECT_THROW(tg.tileOfPixel(static_cast<std::uint32_t>(w * h)), InvariantError);
      }
  EXPECT_GT(grids, 1000);
  EXPECT_THROW(TileGrid(0, 5, 8), InputError);
  EXPECT_THROW(TileGrid(5, 0, 8), InputError);
  EXPECT_THROW(TileGrid(5, 5, 0), InputError);
}

std::vector<std::uint64_t> bruteSamplesPerTile(const TileGrid& tg, std::span<const std::uint16_t> counts) {
  std::vector<std::uint64_t> s(static_cast<std::size_t>(tg.count()), 0);
  for (int y = 0; y < tg.height; ++y)
    for (int x = 0; x < tg.width; ++x)
      s[static_cast<std::size_t>((y / tg.tileSize) * tg.cols() + x / tg.tileSize)] +=
          counts[static_cast<std::size_t>(y * tg.width + x)];
  return s;
}

TEST(SamplesPerTile, RandomCountsMatchAPixelLoop) {
  std::mt19937 rng(17);
  std::uniform_int_distribution<int> c(0, 65535);
  for (const int ts : {1, 3, 4, 7, 16, 128})
    for (int w = 1; w <= 45; w += 4)
      for (int h = 1; h <= 45; h += 5) {
        const TileGrid tg(w, h, ts);
        std::vector<std::uint16_t> counts(static_cast<std::size_t>(w * h));
        for (auto& v : counts) v = static_cast<std::uint16_t>(c(rng));
        EXPECT_EQ(pp5::samplesPerTile(tg, counts), bruteSamplesPerTile(tg, counts)) << w << "x" << h << " / " << ts;
      }
  const TileGrid tg(4, 4, 2);
  std::vector<std::uint16_t> wrong(15);
  EXPECT_THROW(pp5::samplesPerTile(tg, wrong), InvariantError);
}

Grid smallGrid() {
  Grid g;
  g.origin = Vec3(-7.0, -4.5, -3.0);
  g.spacing = Vec3(1.0, 0.8, 1.2);
  g.dims = Index3(15, 12, 9);
  return g;
}

// A few views of the grid: perspective from two sides, orthographic, and one
// with the eye inside.
std::vector<pp5::SampleLattice> smallLattices(const Grid& g) {
  std::vector<pp5::SampleLattice> out;
  struct View {
    const char* projection;
    double az, el, dist;
  };
  for (const View v : {View{"perspective", -120.0, 35.0, 3.2}, View{"perspective", 47.0, -20.0, 2.1},
                       View{"orthographic", 10.0, 80.0, 3.0}, View{"perspective", 200.0, 5.0, 0.3}}) {
    pp5::RenderSettings s;
    s.width = 37;
    s.height = 29;
    s.projection = pp5::enumFromName<pp5::Projection>(v.projection);
    s.azimuthDeg = v.az;
    s.elevationDeg = v.el;
    s.distance = v.dist;
    s.stepMm = 0.45;
    s.maxSamples = 512;
    s.threads = 1;
    out.emplace_back(pp5::makeCamera(s, g), g, s.step(g), s.maxSamples, 1);
  }
  return out;
}

TEST(SamplesPerTile, RealLatticeMatchesAPixelLoop) {
  const Grid g = smallGrid();
  for (const auto& lat : smallLattices(g)) {
    ASSERT_GT(lat.totalSamples(), 1000u);
    for (const int ts : {1, 4, 8, 13, 128}) {
      const TileGrid tg(lat.width(), lat.height(), ts);
      const auto s = pp5::samplesPerTile(tg, lat.counts());
      EXPECT_EQ(s, bruteSamplesPerTile(tg, lat.counts()));
      EXPECT_EQ(std::accumulate(s.begin(), s.end(), std::uint64_t{0}), lat.totalSamples());
    }
  }
}

// ------------------------------------------------------------------ slabs --

std::int64_t surfaceCost(const Index3& n, const Index3& f) {
  return n.y * n.z * f.x + n.z * n.x * f.y + n.x * n.y * f.z;
}

// Checks every promise of the layout for one grid, count and split.
void checkLayout(const Grid& grid, int G, SlabSplit split, int align) {
  SCOPED_TRACE(testing::Message() << "dims " << grid.dims.x << "x" << grid.dims.y << "x" << grid.dims.z << ", " << G
                                  << " GPs, " << pp5::parallel::slabSplitName(split) << ", align " << align);
  const SlabLayout L(grid, G, split, align);
  const Index3 n = grid.dims - Index3(1);
  ASSERT_EQ(L.gps(), G);
  const Index3 parts = L.parts();
  ASSERT_EQ(parts.x * parts.y * parts.z, G);
  if (split == SlabSplit::Longest) {
    // G along the axis with the most cells (ties: the later axis).
    int axis = 2;
    if (n.y > n.z) axis = 1;
    if (n.x > n[axis]) axis = 0;
    for (int a = 0; a < 3; ++a) EXPECT_EQ(parts[a], a == axis ? G : 1);
  } else {
    // The least surface among the factorisations, those with no empty part first.
    auto empties = [&](const Index3& f) { return (f.x > n.x) || (f.y > n.y) || (f.z > n.z); };
    for (int fx = 1; fx <= G; ++fx)
      for (int fy = 1; fy <= G; ++fy)
        for (int fz = 1; fz <= G; ++fz) {
          if (fx * fy * fz != G) continue;
          const Index3 f(fx, fy, fz);
          if (empties(f) && !empties(parts)) continue;
          if (!empties(f) && empties(parts)) {
            ADD_FAILURE() << "chose an empty part although " << fx << "x" << fy << "x" << fz << " has none";
            continue;
          }
          EXPECT_LE(surfaceCost(n, parts), surfaceCost(n, f)) << fx << "x" << fy << "x" << fz << " has less surface";
        }
  }

  // Per axis, the parts' extents (from the boxes of the GPs on that axis).
  for (int a = 0; a < 3; ++a) {
    std::vector<std::int64_t> sizes;
    std::int64_t end = 0;
    for (std::int64_t p = 0; p < parts[a]; ++p) {
      Index3 q(0);
      q[a] = p;
      const int g = static_cast<int>(q.x + parts.x * (q.y + parts.y * q.z));
      const Box3& b = L.ownedCells(g);
      EXPECT_EQ(b.lo[a], end) << "axis " << a << " part " << p << " does not start where the last ended";
      end = b.hi[a];
      sizes.push_back(b.hi[a] - b.lo[a]);
      if (parts[a] <= n[a]) { EXPECT_GT(sizes.back(), 0) << "an empty part with fewer parts than cells"; }
    }
    EXPECT_EQ(end, n[a]);
    const bool aligned = align > 1 && n[a] >= static_cast<std::int64_t>(align) * parts[a];
    const auto [mn, mx] = std::minmax_element(sizes.begin(), sizes.end());
    EXPECT_LE(*mx - *mn, aligned ? align : 1) << "axis " << a << " unbalanced";
    if (aligned) {
      std::int64_t cut = 0;
      for (std::size_t p = 0; p + 1 < sizes.size(); ++p) {
        cut += sizes[p];
        EXPECT_EQ(cut % align, 0) << "axis " << a << " cut " << cut << " not aligned";
      }
    }
  }

  // Every cell exactly one owner, and ownerOfCell agrees with the boxes.
  std::vector<int> owner(static_cast<std::size_t>(std::max<std::int64_t>(0, n.x * n.y * n.z)), -1);
  for (int g = 0; g < G; ++g) {
    const Box3& b = L.ownedCells(g);
    if (b.empty()) continue;
    for (std::int64_t k = b.lo.z; k < b.hi.z; ++k)
      for (std::int64_t j = b.lo.y; j < b.hi.y; ++j)
        for (std::int64_t i = b.lo.x; i < b.hi.x; ++i) {
          ASSERT_TRUE(i >= 0 && j >= 0 && k >= 0 && i < n.x && j < n.y && k < n.z);
          int& o = owner[static_cast<std::size_t>((k * n.y + j) * n.x + i)];
          ASSERT_EQ(o, -1) << "cell " << i << "," << j << "," << k << " owned twice";
          o = g;
        }
  }
  for (std::int64_t k = 0; k < n.z; ++k)
    for (std::int64_t j = 0; j < n.y; ++j)
      for (std::int64_t i = 0; i < n.x; ++i) {
        const int o = owner[static_cast<std::size_t>((k * n.y + j) * n.x + i)];
        ASSERT_NE(o, -1) << "cell " << i << "," << j << "," << k << " has no owner";
        ASSERT_EQ(L.ownerOfCell(Index3(i, j, k)), o);
      }
  EXPECT_THROW(L.ownerOfCell(Index3(n.x, 0, 0)), InvariantError);
  EXPECT_THROW(L.ownerOfCell(Index3(0, -1, 0)), InvariantError);

  // Windows: the owned cells' voxels grown by the ghosts, clipped to the grid.
  for (int ghost = 0; ghost <= 3; ++ghost)
    for (int g = 0; g < G; ++g) {
      const Box3& b = L.ownedCells(g);
      const Box3 w = L.window(g, ghost);
      if (b.empty()) {
        EXPECT_TRUE(w.empty());
        continue;
      }
      Index3 lo(std::numeric_limits<std::int64_t>::max()), hi(std::numeric_limits<std::int64_t>::min());
      for (const std::int64_t k : {b.lo.z, b.hi.z - 1})
        for (const std::int64_t j : {b.lo.y, b.hi.y - 1})
          for (const std::int64_t i : {b.lo.x, b.hi.x - 1})
            for (int c = 0; c < 8; ++c) {  // the cell's 8 voxels, each grown by `ghost`
              const Index3 v(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1));
              lo = glm::min(lo, glm::max(v - Index3(ghost), Index3(0)));
              hi = glm::max(hi, glm::min(v + Index3(ghost + 1), grid.dims));
            }
      EXPECT_EQ(w.lo, lo);
      EXPECT_EQ(w.hi, hi);
    }
}

TEST(SlabLayout, EveryCellOneOwnerBalancedAlignedForSmallGrids) {
  const std::vector<int> ds{2, 3, 5, 8, 9, 13, 17, 20};
  int layouts = 0;
  for (const int dx : ds)
    for (const int dy : ds)
      for (const int dz : ds) {
        Grid g;
        g.origin = Vec3(1.5, -2.0, 0.25);
        g.spacing = Vec3(0.5, 0.7, 1.1);
        g.dims = Index3(dx, dy, dz);
        for (int G = 1; G <= 16; ++G)
          for (const SlabSplit split : {SlabSplit::Longest, SlabSplit::Grid3d})
            for (const int align : {1, 3, 8}) {
              checkLayout(g, G, split, align);
              ++layouts;
              if (HasFatalFailure()) return;
            }
      }
  EXPECT_EQ(layouts, 8 * 8 * 8 * 16 * 2 * 3);
}

TEST(SlabLayout, Grid3dMakesCubes) {
  Grid g;
  auto parts = [&](Index3 dims, int G) {
    g.dims = dims;
    return SlabLayout(g, G, SlabSplit::Grid3d).parts();
  };
  EXPECT_EQ(parts(Index3(65), 8), Index3(2, 2, 2));
  EXPECT_EQ(parts(Index3(65), 4), Index3(1, 2, 2));  // ties go to z, then y
  EXPECT_EQ(parts(Index3(65), 2), Index3(1, 1, 2));
  EXPECT_EQ(parts(Index3(65), 7), Index3(1, 1, 7));
  EXPECT_EQ(parts(Index3(65, 33, 17), 8), Index3(4, 2, 1));  // 16^3 boxes
  EXPECT_EQ(parts(Index3(129, 129, 33), 16), Index3(4, 4, 1));
  EXPECT_EQ(parts(Index3(3, 3, 3), 16), Index3(2, 2, 4));  // no split without empty parts
  // Aligned to 8 where there is room: 64 cells in 3 parts.
  g.dims = Index3(65, 65, 65);
  const SlabLayout L(g, 3, SlabSplit::Longest, 8);
  EXPECT_EQ(L.ownedCells(0).hi.z, 24);
  EXPECT_EQ(L.ownedCells(1).hi.z, 48);
  EXPECT_EQ(L.ownedCells(2).hi.z, 64);
}

TEST(SlabLayout, NamesAndInvalidArguments) {
  for (const SlabSplit s : {SlabSplit::Longest, SlabSplit::Grid3d})
    EXPECT_EQ(pp5::parallel::slabSplitFromName(pp5::parallel::slabSplitName(s)), s);
  EXPECT_EQ(inputErrorMessage([] { pp5::parallel::slabSplitFromName("octree"); }),
            "parallel.slab_split = \"octree\" is not one of longest, 3d");
  const Grid g = smallGrid();
  EXPECT_THROW(SlabLayout(g, 0, SlabSplit::Longest), InvariantError);
  EXPECT_THROW(SlabLayout(g, 2, SlabSplit::Grid3d, 0), InvariantError);
}

// Every lattice sample's stencil cell has exactly one owner, and the owners'
// per-tile counts add up to the tile's cache size.
TEST(SlabLayout, EveryLatticeSampleHasExactlyOneOwner) {
  const Grid grid = smallGrid();
  const auto lattices = smallLattices(grid);
  for (std::size_t v = 0; v < lattices.size(); ++v) {
    const auto& lat = lattices[v];
    const TileGrid tg(lat.width(), lat.height(), 8);
    const auto expected = pp5::samplesPerTile(tg, lat.counts());
    // The cells, computed once per view.
    std::vector<Index3> cells;
    std::vector<int> tileOf;
    for (std::uint32_t p = 0; p < lat.pixelCount(); ++p)
      for (std::uint32_t k = 0; k < lat.count(p); ++k) {
        cells.push_back(pp5::gp::stencilCell(lat, p, k));
        tileOf.push_back(tg.tileOfPixel(p));
      }
    for (int G = 1; G <= 16; ++G)
      for (const SlabSplit split : {SlabSplit::Longest, SlabSplit::Grid3d})
        for (const int align : {1, 4}) {
          SCOPED_TRACE(testing::Message() << "view " << v << ", " << G << " GPs, " << pp5::parallel::slabSplitName(split)
                                          << ", align " << align);
          const SlabLayout L(grid, G, split, align);
          std::vector<std::vector<std::uint64_t>> perOwner(static_cast<std::size_t>(G),
                                                           std::vector<std::uint64_t>(expected.size(), 0));
          for (std::size_t s = 0; s < cells.size(); ++s) {
            int owners = 0, who = -1;
            for (int g = 0; g < G; ++g)
              if (L.ownedCells(g).contains(cells[s].x, cells[s].y, cells[s].z)) {
                ++owners;
                who = g;
              }
            ASSERT_EQ(owners, 1) << "sample " << s << " in cell " << cells[s].x << "," << cells[s].y << ","
                                 << cells[s].z;
            ASSERT_EQ(L.ownerOfCell(cells[s]), who);
            // The owner's window (no ghosts) holds the sample's 8 voxels.
            ASSERT_TRUE(L.window(who, 0).contains(cells[s].x + 1, cells[s].y + 1, cells[s].z + 1));
            ++perOwner[static_cast<std::size_t>(who)][static_cast<std::size_t>(tileOf[s])];
          }
          for (std::size_t t = 0; t < expected.size(); ++t) {
            std::uint64_t sum = 0;
            for (int g = 0; g < G; ++g) sum += perOwner[static_cast<std::size_t>(g)][t];
            EXPECT_EQ(sum, expected[t]) << "tile " << t;
          }
        }
  }
}

// ------------------------------------------------------------- touched --

bool inside(const WorldBox& b, const Vec3& p) {
  return p.x >= b.lo.x && p.y >= b.lo.y && p.z >= b.lo.z && p.x <= b.hi.x && p.y <= b.hi.y && p.z <= b.hi.z;
}


std::vector<int> bruteTouched(const SlabLayout& L, const WorldBox& box, int ghost, const ReconSettings& recon) {
  std::vector<int> out;
  const Grid& g = L.grid();
  for (int gp = 0; gp < L.gps(); ++gp) {
    const Box3 w = L.reach(gp, ghost, recon);
    bool hit = false;
    for (std::int64_t k = w.lo.z; k < w.hi.z && !hit; ++k)
      for (std::int64_t j = w.lo.y; j < w.hi.y && !hit; ++j)
        for (std::int64_t i = w.lo.x; i < w.hi.x && !hit; ++i)
          hit = inside(box, g.voxelToWorld(Vec3(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k))));
    if (hit) out.push_back(gp);
  }
  return out;
}

TEST(GpsTouched, MatchesABruteForceVoxelLoop) {
  std::mt19937 rng(77);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  Grid g;
  g.origin = Vec3(-3.3, 1.7, 0.4);
  g.spacing = Vec3(0.7, 1.3, 0.45);
  int checks = 0, nonTrivial = 0;
  for (const Index3 dims : {Index3(9, 7, 11), Index3(17, 5, 3), Index3(2, 13, 8)}) {
    g.dims = dims;
    // Boxes: random ones in and around the grid, degenerate ones exactly on
    // voxel positions (closed intervals), empty ones, and everything.
    std::vector<WorldBox> boxes;
    const Vec3 lo = g.minCorner() - 2.0 * g.spacing, ext = g.maxCorner() - g.minCorner() + 4.0 * g.spacing;
    for (int i = 0; i < 40; ++i) {
      const Vec3 a = lo + Vec3(U(rng), U(rng), U(rng)) * ext, b = lo + Vec3(U(rng), U(rng), U(rng)) * ext;
      boxes.push_back({glm::min(a, b), glm::max(a, b)});
    }
    for (int i = 0; i < 20; ++i) {
      const Index3 v(static_cast<std::int64_t>(U(rng) * dims.x), static_cast<std::int64_t>(U(rng) * dims.y),
                     static_cast<std::int64_t>(U(rng) * dims.z));
      const Vec3 p = g.voxelToWorld(Vec3(v));
      boxes.push_back({p, p});
      const Vec3 q = g.voxelToWorld(Vec3(v + Index3(1)));
      boxes.push_back({p, q});
      boxes.push_back({glm::min(p, q) + Vec3(1e-9), glm::max(p, q) - Vec3(1e-9)});  // strictly between
    }
    boxes.push_back({Vec3(1.0), Vec3(0.0)});
    boxes.push_back({Vec3(-1e300), Vec3(1e300)});
    boxes.push_back({g.maxCorner() + Vec3(1.0), g.maxCorner() + Vec3(2.0)});
    // The tent's windows as they are, and grown to whole motion-vector cells.
    ReconSettings plain, motion;
    motion.tent.replacement = pp5::gp::Replacement::MotionVector;
    motion.tent.motionVectorBrick = 4;
    for (const ReconSettings* recon : {&plain, &motion})
      for (int G = 1; G <= 16; ++G)
        for (const SlabSplit split : {SlabSplit::Longest, SlabSplit::Grid3d})
          for (const int align : {1, 2}) {
            const SlabLayout L(g, G, split, align);
            for (int ghost = 0; ghost <= 3; ++ghost) {
              std::vector<Box3> reaches;
              for (int k = 0; k < G; ++k) reaches.push_back(L.reach(k, ghost, *recon));
              for (std::size_t b = 0; b < boxes.size(); ++b) {
                const auto expect = bruteTouched(L, boxes[b], ghost, *recon);
                ASSERT_EQ(pp5::parallel::gpsTouched(g, reaches, boxes[b]), expect)
                    << "dims " << dims.x << "x" << dims.y << "x" << dims.z << ", " << G << " GPs, "
                    << pp5::parallel::slabSplitName(split) << ", ghost " << ghost << ", box " << b << ", "
                    << pp5::enumName(recon->tent.replacement);
                ++checks;
                if (!expect.empty() && static_cast<int>(expect.size()) < G) ++nonTrivial;
              }
            }
          }
  }
  EXPECT_GT(checks, 50000);
  EXPECT_GT(nonTrivial, 10000);
}

}  // namespace
