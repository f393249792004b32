// The change tracker (rendering/change_tracker.hpp) against brute force: shading
// only the runs it lists gives the bits of a full re-shade, for random
// changes of values, visible and transparent, for every voxel type, in both
// its forms (comparing with a copy, and told the changed rows); and the
// cells it marks are exactly those with a changed voxel among their 8.
#include <gtest/gtest.h>

#include <algorithm>
#include <climits>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "rendering/change_tracker.hpp"
#include "rendering/shading.hpp"

namespace {

using namespace pp5;
using namespace pp5::gp;

Grid smallGrid() {
  Grid g;
  g.dims = Index3(23, 17, 13);
  g.spacing = Vec3(0.5, 0.7, 0.6);
  g.origin = Vec3(-3.0, 2.0, 1.0);
  return g;
}

Camera cameraFor(const Grid& g) {
  Camera c;
  c.target = g.voxelToWorld(0.5 * Vec3(g.dims - Index3(1)));
  c.eye = c.target + Vec3(40.0, -25.0, 30.0);
  c.up = Vec3(0, 0, 1);
  return c;
}

class Tracker : public ::testing::TestWithParam<std::tuple<ScalarType, bool, bool>> {};

// `b` as disjoint boxes: cut in two along x and in up to three along z, as
// the GP shares hand the tracker several boxes.
std::vector<Box3> pieces(const Box3& b) {
  std::vector<Box3> out;
  const std::int64_t xm = (b.lo.x + b.hi.x) / 2;
  const std::int64_t z1 = b.lo.z + (b.hi.z - b.lo.z) / 3, z2 = b.lo.z + 2 * (b.hi.z - b.lo.z) / 3;
  for (const auto& [x0, x1] : {std::pair{b.lo.x, xm}, std::pair{xm, b.hi.x}})
    for (const auto& [za, zb] : {std::pair{b.lo.z, z1}, std::pair{z1, z2}, std::pair{z2, b.hi.z}}) {
      const Box3 p{Index3(x0, b.lo.y, za), Index3(x1, b.hi.y, zb)};
      if (!p.empty()) out.push_back(p);
    }
  return out;
}

TEST_P(Tracker, ShadingTheRunsEqualsAFullReshade) {
  const auto [type, grey, gradientOpacity] = GetParam();
  const Grid g = smallGrid();
  Volume v;
  v.allocate(g, type);
  std::mt19937 rng(7);
  // Water below the opacity ramp with tissue in it: most changes are to
  // transparent values, as in a real sweep. Every third row starts as water
  // only, and its changes bring tissue rarely (a row whose values are all
  // transparent is one the reported form need not read).
  auto randomValue = [&](double tissue = 0.2) {
    return std::uniform_real_distribution<double>(0.0, 1.0)(rng) >= tissue
               ? std::uniform_real_distribution<double>(0.0, 20.0)(rng)
               : std::uniform_real_distribution<double>(20.0, 255.0)(rng);
  };
  auto tissueIn = [](std::size_t voxel, const Grid& grid, bool first) {
    const auto row = static_cast<std::int64_t>(voxel) / grid.dims.x;
    return row % 3 == 0 ? (first ? 0.0 : 0.01) : 0.2;
  };
  for (std::size_t i = 0; i < g.voxelCount(); ++i) v.setValue(i, randomValue(tissueIn(i, g, true)));
  const TransferFunction tf;
  ShadeSettings s;
  s.greyValues = grey;
  s.gradientOpacity = gradientOpacity;  // the opacity then reads the neighbours too
  s.threads = 2;
  const Camera cam = cameraFor(g);
  const Box3 all{Index3(0), g.dims};
  ShadeBuffer buf(g);
  shade(v, tf, s, cam, all, buf);
  ChangeTracker tracker(v, buf, true);
  // The reported form, with a shade buffer of its own.
  ShadeBuffer bufR = buf;
  ChangeTracker told(v, bufR, false);
  // ... and clipped to one box instead of the list (a share of one region).
  ShadeBuffer bufB = buf;
  ChangeTracker toldBox(v, bufB, false);
  EXPECT_LT(told.memoryBytes(), tracker.memoryBytes());

  for (int round = 0; round < 12; ++round) {
    // Change values in a random box (the "dirty region"), some of them.
    Index3 lo, hi;
    for (int a = 0; a < 3; ++a) {
      const auto n = g.dims[a];
      lo[a] = std::uniform_int_distribution<std::int64_t>(0, n - 2)(rng);
      hi[a] = std::uniform_int_distribution<std::int64_t>(lo[a] + 1, n)(rng);
    }
    const Box3 dirty{lo, hi};
    // What the reconstructor would report: per row, the changed voxels'
    // range, widened by up to two voxels on either side (the runs may hold
    // unchanged ones) and at times cut in two overlapping halves.
    std::vector<RowRun> reported;
    for (std::int64_t k = lo.z; k < hi.z; ++k)
      for (std::int64_t j = lo.y; j < hi.y; ++j) {
        std::int32_t a = INT32_MAX, z = -1;
        for (std::int64_t i = lo.x; i < hi.x; ++i)
          if (std::uniform_int_distribution<int>(0, 2)(rng) == 0) {
            const auto at = static_cast<std::size_t>((k * g.dims.y + j) * g.dims.x + i);
            v.setValue(at, randomValue(tissueIn(at, g, false)));
            a = std::min(a, static_cast<std::int32_t>(i));
            z = static_cast<std::int32_t>(i);
          }
        if (a > z) continue;
        a = std::max(0, a - std::uniform_int_distribution<std::int32_t>(0, 2)(rng));
        z = std::min(static_cast<std::int32_t>(g.dims.x - 1), z + std::uniform_int_distribution<std::int32_t>(0, 2)(rng));
        const auto jj = static_cast<std::int32_t>(j), kk = static_cast<std::int32_t>(k);
        // The bound on the new values: the run's largest (at times not known).
        auto bound = [&](std::int32_t x0, std::int32_t x1) {
          if (std::uniform_int_distribution<int>(0, 5)(rng) == 0) return std::numeric_limits<float>::infinity();
          float m = -std::numeric_limits<float>::infinity();
          for (std::int32_t x = x0; x <= x1; ++x)
            m = std::max(m, static_cast<float>(v.value(static_cast<std::size_t>((k * g.dims.y + j) * g.dims.x + x))));
          return m;
        };
        if (z - a >= 2 && std::uniform_int_distribution<int>(0, 1)(rng) == 0) {
          const std::int32_t m = (a + z) / 2;
          reported.push_back({jj, kk, m - 1, z, bound(m - 1, z)});
          reported.push_back({jj, kk, a, m, bound(a, m)});
        } else {
          reported.push_back({jj, kk, a, z, bound(a, z)});
        }
      }
    std::shuffle(reported.begin(), reported.end(), rng);
    const Box3 needed = dirty.grown(1).intersect(all);
    const std::vector<Box3> within = pieces(needed);
    std::uint64_t withinVoxels = 0;
    for (const Box3& w : within) withinVoxels += w.voxelCount();
    ASSERT_EQ(withinVoxels, needed.voxelCount());
    const std::vector<Box3> runs =
        tracker.shadingRuns(v, std::span<const Box3>(&needed, 1), within, grey ? nullptr : &tf);
    std::vector<std::int64_t> changed;
    shade(v, tf, s, cam, runs, buf, &changed);

    const std::vector<Box3> runsR = told.shadingRuns(v, reported, within, grey ? nullptr : &tf);
    std::vector<std::int64_t> changedR;
    shade(v, tf, s, cam, runsR, bufR, &changedR);
    // The box: the grid's upper part from y = 2 on, so that some changes lie outside it.
    const Box3 part{Index3(0, 2, 0), g.dims};
    const std::vector<Box3> runsB = toldBox.shadingRuns(v, reported, part, grey ? nullptr : &tf);
    for (const Box3& r : runsB) ASSERT_EQ(r.intersect(part), r) << "runs stay in the box";
    std::vector<std::int64_t> changedB;
    shade(v, tf, s, cam, runsB, bufB, &changedB);
    toldBox.setShadeChanges(changedB, bufB);

    ShadeBuffer full(g);
    shade(v, tf, s, cam, all, full);
    ASSERT_EQ(std::memcmp(full.data(), buf.data(), g.voxelCount() * sizeof(ShadeVoxel)), 0) << "round " << round;
    ASSERT_EQ(std::memcmp(full.data(), bufR.data(), g.voxelCount() * sizeof(ShadeVoxel)), 0) << "round " << round;
    // The box's shades are the full re-shade's inside it (outside, another GP shades).
    for (std::int64_t k = 0; k < g.dims.z; ++k)
      for (std::int64_t j = part.lo.y; j < g.dims.y; ++j)
        for (std::int64_t i = 0; i < g.dims.x; ++i) {
          ASSERT_EQ(bufB.at(g.linear(i, j, k)), full.at(g.linear(i, j, k)))
              << "round " << round << " voxel " << i << " " << j << " " << k;
        }
    EXPECT_EQ(changedR, changed) << "both forms find the same changed shades";
    std::uint64_t runVoxels = 0, runVoxelsR = 0;
    for (const Box3& r : runs) runVoxels += r.voxelCount();
    for (const Box3& r : runsR) runVoxelsR += r.voxelCount();
    if (!grey) {
      EXPECT_LT(runVoxels, needed.voxelCount()) << "transparent voxels are left out";
      EXPECT_LT(runVoxelsR, needed.voxelCount()) << "transparent voxels are left out";
    }
    told.setShadeChanges(changedR, bufR);

    // The cells: marked exactly where one of the 8 voxels changed its shade.
    tracker.setShadeChanges(changed, buf);
    std::vector<std::uint8_t> flag(g.voxelCount(), 0);
    for (const std::int64_t c : changed) flag[static_cast<std::size_t>(c)] = 1;
    for (std::size_t c = 1; c < changed.size(); ++c) ASSERT_LT(changed[c - 1], changed[c]) << "ascending, unique";
    std::size_t marked = 0;
    for (std::int64_t k = 0; k + 1 < g.dims.z; ++k)
      for (std::int64_t j = 0; j + 1 < g.dims.y; ++j)
        for (std::int64_t i = 0; i + 1 < g.dims.x; ++i) {
          bool any = false;
          for (int c = 0; c < 8; ++c)
            any = any || flag[static_cast<std::size_t>(((k + (c >> 2)) * g.dims.y + j + ((c >> 1) & 1)) * g.dims.x + i +
                                                       (c & 1))];
          const auto idx = static_cast<std::size_t>((k * g.dims.y + j) * g.dims.x + i);
          ASSERT_EQ(tracker.changedCells().changed(static_cast<std::int64_t>(idx)), any) << "cell " << i << " " << j << " " << k;
          marked += any;
        }
    // Every changed voxel's 8^3 brick is listed, and only those.
    for (const std::int64_t c : changed)
      EXPECT_TRUE(tracker.changedBricks().containsVoxel(c % g.dims.x, (c / g.dims.x) % g.dims.y,
                                                        c / (g.dims.x * g.dims.y)));
    EXPECT_LE(tracker.changedBricks().bricks().size(), changed.size());
    if (changed.empty()) {
      EXPECT_EQ(marked, 0u);
    }
  }
  // Nothing changed: nothing to shade.
  const std::vector<Box3> none = tracker.shadingRuns(v, std::span<const Box3>(&all, 1), std::span<const Box3>(&all, 1), &tf);
  EXPECT_TRUE(none.empty());
  EXPECT_TRUE(told.shadingRuns(v, std::span<const RowRun>(), std::span<const Box3>(&all, 1), &tf).empty());
}

// Each update marks its cells with a new value, and the marks are cleared
// only when the values wrap (every 255 updates): across several wraps, the
// marked cells are exactly those of the last update's voxels.
TEST(TrackerCells, MarksStayExactAcrossTheWrap) {
  Grid g;
  g.dims = Index3(9, 7, 6);
  Volume v;
  v.allocate(g, ScalarType::F32);
  const ShadeBuffer none(g);
  ChangeTracker tracker(v, none, false);
  std::mt19937 rng(5);
  const auto n = static_cast<std::int64_t>(g.voxelCount());
  for (int update = 0; update < 600; ++update) {
    std::vector<std::int64_t> voxels;
    const int count = std::uniform_int_distribution<int>(0, 4)(rng);
    for (int c = 0; c < count; ++c) voxels.push_back(std::uniform_int_distribution<std::int64_t>(0, n - 1)(rng));
    std::sort(voxels.begin(), voxels.end());
    voxels.erase(std::unique(voxels.begin(), voxels.end()), voxels.end());
    tracker.setShadeChanges(voxels, none);
    for (std::int64_t k = 0; k + 1 < g.dims.z; ++k)
      for (std::int64_t j = 0; j + 1 < g.dims.y; ++j)
        for (std::int64_t i = 0; i + 1 < g.dims.x; ++i) {
          bool any = false;
          for (const std::int64_t x : voxels) {
            const std::int64_t xi = x % g.dims.x, xj = (x / g.dims.x) % g.dims.y, xk = x / (g.dims.x * g.dims.y);
            any = any || (xi - i >= 0 && xi - i <= 1 && xj - j >= 0 && xj - j <= 1 && xk - k >= 0 && xk - k <= 1);
          }
          ASSERT_EQ(tracker.changedCells().changed((k * g.dims.y + j) * g.dims.x + i), any)
              << "update " << update << ", cell " << i << " " << j << " " << k;
        }
  }
}

INSTANTIATE_TEST_SUITE_P(Types, Tracker,
                         ::testing::Combine(::testing::Values(ScalarType::U8, ScalarType::U16, ScalarType::F32),
                                            ::testing::Bool(), ::testing::Bool()));

// Float values are scanned four at a time (SSE2), the integer types one at a
// time: with the same whole-number values in both, the two trackers list
// the same runs, box for box, whatever the rows' lengths and offsets.
TEST(Tracker, FloatScanListsTheRunsOfTheScalarScan) {
  const Grid g = smallGrid();  // 23 voxels a row: every row ends in a partial group
  Volume f, u;
  f.allocate(g, ScalarType::F32);
  u.allocate(g, ScalarType::U16);
  std::mt19937 rng(31);
  auto randomValue = [&] {
    return static_cast<double>(std::uniform_real_distribution<double>(0.0, 1.0)(rng) < 0.7
                                   ? std::uniform_int_distribution<int>(0, 20)(rng)
                                   : std::uniform_int_distribution<int>(21, 255)(rng));
  };
  for (std::size_t i = 0; i < g.voxelCount(); ++i) {
    const double x = randomValue();
    f.setValue(i, x);
    u.setValue(i, x);
  }
  const TransferFunction tf;
  const ShadeBuffer none(g);
  ChangeTracker tf32(f, none, true), tu16(u, none, true);
  const Box3 all{Index3(0), g.dims};
  int listed = 0;
  for (int round = 0; round < 40; ++round) {
    Index3 lo, hi;
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::uniform_int_distribution<std::int64_t>(0, g.dims[a] - 1)(rng);
      hi[a] = std::uniform_int_distribution<std::int64_t>(lo[a] + 1, g.dims[a])(rng);
    }
    const Box3 dirty{lo, hi};
    for (std::int64_t k = lo.z; k < hi.z; ++k)
      for (std::int64_t j = lo.y; j < hi.y; ++j)
        for (std::int64_t i = lo.x; i < hi.x; ++i)
          if (std::uniform_int_distribution<int>(0, 3)(rng) == 0) {
            const double x = randomValue();
            const auto at = static_cast<std::size_t>((k * g.dims.y + j) * g.dims.x + i);
            f.setValue(at, x);
            u.setValue(at, x);
          }
    const Box3 needed = dirty.grown(1).intersect(all);
    const std::vector<Box3> within = pieces(needed);
    for (const TransferFunction* t : {&tf, static_cast<const TransferFunction*>(nullptr)}) {
      const std::vector<Box3> a = tf32.shadingRuns(f, std::span<const Box3>(&needed, 1), within, t);
      const std::vector<Box3> b = tu16.shadingRuns(u, std::span<const Box3>(&needed, 1), within, t);
      ASSERT_EQ(a.size(), b.size()) << "round " << round;
      for (std::size_t r = 0; r < a.size(); ++r) {
        ASSERT_EQ(a[r].lo, b[r].lo) << "round " << round << " run " << r;
        ASSERT_EQ(a[r].hi, b[r].hi) << "round " << round << " run " << r;
      }
      if (t) {
        listed += !a.empty();
        continue;
      }
      // The second pass (no transfer function) sees no change: the copies took the values.
      EXPECT_TRUE(a.empty());
    }
  }
  EXPECT_GT(listed, 30);
}

// A change to water next to one voxel of tissue, from each of its four face
// neighbour rows in turn (the rows that a row of water's change matters to
// only through a neighbour): the tissue's gradient, so its shade, changes,
// and the reported form, listed and as one box, shades it as a full
// re-shade does.
TEST(Tracker, AChangeInWaterReachesTissueInEveryNeighbourRow) {
  const Grid g = smallGrid();
  Volume v;
  v.allocate(g, ScalarType::F32);
  for (std::size_t i = 0; i < g.voxelCount(); ++i) v.setValue(i, 5.0);  // water: below the ramp
  const std::int64_t i0 = 11, j0 = 8, k0 = 6;
  v.setValue(g.linear(i0, j0, k0), 200.0);
  const TransferFunction tf;
  ASSERT_TRUE(tf.transparentUpTo(19.0f));
  ASSERT_FALSE(tf.transparentUpTo(200.0f));
  ShadeSettings s;
  s.threads = 1;
  const Camera cam = cameraFor(g);
  const Box3 all{Index3(0), g.dims};
  ShadeBuffer listed(g), boxed(g);
  shade(v, tf, s, cam, all, listed);
  shade(v, tf, s, cam, all, boxed);
  ChangeTracker told(v, listed, false), toldBox(v, boxed, false);
  const std::int64_t offsets[4][2] = {{-1, 0}, {1, 0}, {0, -1}, {0, 1}};
  for (const auto& o : offsets) {
    const std::int64_t j = j0 + o[0], k = k0 + o[1];
    const ShadeVoxel before = listed.at(g.linear(i0, j0, k0));
    v.setValue(g.linear(i0, j, k), 19.0);  // still water
    const std::vector<RowRun> reported{{static_cast<std::int32_t>(j), static_cast<std::int32_t>(k),
                                        static_cast<std::int32_t>(i0), static_cast<std::int32_t>(i0), 19.0f}};
    std::vector<std::int64_t> changed, changedB;
    shade(v, tf, s, cam, told.shadingRuns(v, reported, std::span<const Box3>(&all, 1), &tf), listed, &changed);
    told.setShadeChanges(changed, listed);
    shade(v, tf, s, cam, toldBox.shadingRuns(v, reported, all, &tf), boxed, &changedB);
    toldBox.setShadeChanges(changedB, boxed);
    ShadeBuffer full(g);
    shade(v, tf, s, cam, all, full);
    ASSERT_FALSE(full.at(g.linear(i0, j0, k0)) == before) << "the change reaches the tissue's shade";
    ASSERT_EQ(std::memcmp(full.data(), listed.data(), g.voxelCount() * sizeof(ShadeVoxel)), 0) << o[0] << " " << o[1];
    ASSERT_EQ(std::memcmp(full.data(), boxed.data(), g.voxelCount() * sizeof(ShadeVoxel)), 0) << o[0] << " " << o[1];
  }
}

}  // namespace
