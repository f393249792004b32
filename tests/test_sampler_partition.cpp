// Ray-sampling restricted to a GP's share (SamplerOptions::ownedCells for the
// `slab` partitioning, SamplerOptions::workTiles for `tile`): over a partition
// every sample is emitted exactly once, with the unrestricted sampler's bits.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <mutex>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "core/camera.hpp"
#include "core/error.hpp"
#include "core/grid.hpp"
#include "core/render_settings.hpp"
#include "rendering/dbuffer.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/ray_sampler.hpp"
#include "core/sample_lattice.hpp"
#include "rendering/shade_buffer.hpp"

#include "geometry_test_util.hpp"

namespace {

using pp5::Camera;
using pp5::Grid;
using pp5::Index3;
using pp5::Projection;
using pp5::RaySample;
using pp5::RenderSettings;
using pp5::Vec3;
using pp5::gp::Box3;
using pp5::gp::DBuffer;
using pp5::gp::EmptySpaceMap;
using pp5::SampleLattice;
using pp5::gp::SamplerOptions;
using pp5::gp::ShadeBuffer;
using pp5::gp::ShadeVoxel;
using pp5::gp::WorldBox;

Grid smallGrid() {
  Grid g;
  g.origin = Vec3(-12.0, -9.5, -10.0);
  g.spacing = Vec3(1.0, 0.9, 1.1);
  g.dims = Index3(27, 22, 19);
  return g;
}

using pp5::test::gridCentre;
using pp5::test::randomUnit;

// A random view of the grid; eyeInside: the eye in the grid's box.
Camera randomCamera(std::mt19937& rng, const Grid& g, Projection proj, bool eyeInside, int w, int h) {
  return pp5::test::randomCamera(rng, g, proj, eyeInside, w, h,
                                 {.eyeLo = 0.15, .eyeSpan = 0.7, .fovMinDeg = 25.0, .fovSpanDeg = 60.0, .orthoSpan = 1.2});
}

// Random premultiplied voxels in a few random balls and scattered single
// voxels; transparent elsewhere (and in some voxels of the balls), so the
// empty-space map has empty and visible bricks.
ShadeBuffer randomShade(const Grid& g, std::mt19937& rng, int balls = 4) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  ShadeBuffer s(g);
  std::vector<std::pair<Vec3, double>> bs;
  for (int i = 0; i < balls; ++i)
    bs.emplace_back(g.voxelToWorld(Vec3(g.dims) * Vec3(u(rng), u(rng), u(rng))), 3.0 + 5.0 * u(rng));
  auto setRandom = [&](ShadeVoxel& v) {
    v.a = static_cast<std::uint8_t>(1 + rng() % 255);
    v.r = static_cast<std::uint8_t>(rng() % (v.a + 1u));
    v.g = static_cast<std::uint8_t>(rng() % (v.a + 1u));
    v.b = static_cast<std::uint8_t>(v.a / 2);
  };
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j)
      for (std::int64_t i = 0; i < g.dims.x; ++i) {
        const Vec3 p = g.voxelToWorld(Vec3(i, j, k));
        bool in = false;
        for (const auto& [c, r] : bs) in = in || glm::length(p - c) <= r;
        if (!in || rng() % 6 == 0) continue;
        setRandom(s.at(g.linear(i, j, k)));
      }
  for (int n = 0; n < 6; ++n)
    setRandom(s.at(g.linear(rng() % g.dims.x, rng() % g.dims.y, rng() % g.dims.z)));
  return s;
}

RenderSettings settingsFor(int threads) {
  RenderSettings s;
  s.threads = threads;
  s.opacityUnitMm = 1.0;
  return s;
}

bool keyLess(const RaySample& a, const RaySample& b) { return a.pixel != b.pixel ? a.pixel < b.pixel : a.k < b.k; }

std::vector<RaySample> sorted(std::vector<RaySample> v) {
  std::sort(v.begin(), v.end(), keyLess);
  return v;
}

bool sameBits(const std::vector<RaySample>& a, const std::vector<RaySample>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(RaySample)) == 0);
}

::testing::AssertionResult noDuplicates(const std::vector<RaySample>& sortedSamples) {
  for (std::size_t i = 1; i < sortedSamples.size(); ++i)
    if (sortedSamples[i].pixel == sortedSamples[i - 1].pixel && sortedSamples[i].k == sortedSamples[i - 1].k)
      return ::testing::AssertionFailure() << "duplicate sample: pixel " << sortedSamples[i].pixel << " k "
                                           << sortedSamples[i].k;
  return ::testing::AssertionSuccess();
}

// The sampler to run: sampleAll, or sampleRegion with a D-buffer and
// optional maps (`space`, and `before` with it).
struct Sampler {
  const ShadeBuffer* shade;
  const SampleLattice* lattice;
  const DBuffer* dbuffer = nullptr;  // null: sampleAll
  const EmptySpaceMap* space = nullptr;
  const EmptySpaceMap* before = nullptr;

  std::vector<RaySample> operator()(int threads, const SamplerOptions& opt = {}) const {
    pp5::gp::SampleCollector col;
    if (dbuffer) pp5::gp::sampleRegion(*shade, *lattice, *dbuffer, settingsFor(threads), col, space, opt, before);
    else pp5::gp::sampleAll(*shade, *lattice, settingsFor(threads), col, space, opt);
    return col.samples();
  }
};

// Cut positions along an axis of n cells: 0 .. n with random cuts between,
// some repeated (empty parts) and some one cell apart; the outer ones
// sometimes beyond the grid (the box is clipped to the cells).
std::vector<std::int64_t> randomCuts(std::mt19937& rng, std::int64_t n, int inner) {
  std::vector<std::int64_t> c;
  c.push_back(rng() % 3 == 0 ? -static_cast<std::int64_t>(1 + rng() % 4) : 0);
  for (int i = 0; i < inner; ++i) {
    const std::int64_t x = static_cast<std::int64_t>(rng() % static_cast<std::uint64_t>(n + 1));
    c.push_back(x);
    if (rng() % 4 == 0) c.push_back(std::min(n, x + 1));  // a part of one cell
    if (rng() % 5 == 0) c.push_back(x);                    // an empty part
  }
  c.push_back(rng() % 3 == 0 ? n + static_cast<std::int64_t>(1 + rng() % 4) : n);
  std::sort(c.begin(), c.end());
  return c;
}

// A partition of the cells into boxes: slabs along one axis, or a 3D grid of
// boxes, by random cuts.
std::vector<Box3> randomPartition(std::mt19937& rng, const Index3& cellDims, bool slabs) {
  std::vector<std::int64_t> cuts[3];
  const int slabAxis = static_cast<int>(rng() % 3);
  for (int a = 0; a < 3; ++a) {
    if (slabs && a != slabAxis) cuts[a] = {0, cellDims[a]};
    else
      cuts[a] = randomCuts(rng, cellDims[a], slabs ? 2 + static_cast<int>(rng() % 5) : 1 + static_cast<int>(rng() % 2));
  }
  std::vector<Box3> parts;
  for (std::size_t z = 0; z + 1 < cuts[2].size(); ++z)
    for (std::size_t y = 0; y + 1 < cuts[1].size(); ++y)
      for (std::size_t x = 0; x + 1 < cuts[0].size(); ++x)
        parts.push_back(Box3{Index3(cuts[0][x], cuts[1][y], cuts[2][z]),
                             Index3(cuts[0][x + 1], cuts[1][y + 1], cuts[2][z + 1])});
  return parts;
}

std::string describe(const Box3& b) {
  return "[" + std::to_string(b.lo.x) + "," + std::to_string(b.lo.y) + "," + std::to_string(b.lo.z) + ") - [" +
         std::to_string(b.hi.x) + "," + std::to_string(b.hi.y) + "," + std::to_string(b.hi.z) + ")";
}

// Runs `run` once per part (alternating 1 and 2 threads, and checking that
// the other count gives the same bits), checks that each part's samples have
// their stencil cell in the part, and that the parts' union, sorted, is the
// unrestricted output sorted, bit for bit, without duplicates. Returns how
// many parts emitted something.
int checkPartition(const Sampler& run, const std::vector<RaySample>& wholeSorted, const std::vector<Box3>& parts) {
  const SampleLattice& lat = *run.lattice;
  std::vector<RaySample> all;
  int nonEmpty = 0;
  for (std::size_t i = 0; i < parts.size(); ++i) {
    SCOPED_TRACE("part " + describe(parts[i]));
    SamplerOptions opt;
    opt.tileSize = 8;
    opt.ownedCells = parts[i];
    const int threads = 1 + static_cast<int>(i % 2);
    const auto mine = run(threads, opt);
    EXPECT_TRUE(sameBits(mine, run(3 - threads, opt))) << "thread counts differ";
    for (const auto& s : mine) {
      const Index3 c = pp5::gp::stencilCell(lat, s.pixel, s.k);
      if (!parts[i].contains(c.x, c.y, c.z)) {
        ADD_FAILURE() << "pixel " << s.pixel << " k " << s.k << " cell " << c.x << "," << c.y << "," << c.z
                      << " outside its part";
        break;
      }
    }
    nonEmpty += !mine.empty();
    all.insert(all.end(), mine.begin(), mine.end());
  }
  all = sorted(std::move(all));
  EXPECT_TRUE(noDuplicates(all));
  EXPECT_EQ(all.size(), wholeSorted.size());
  EXPECT_TRUE(sameBits(all, wholeSorted)) << "the parts' union differs from the whole";
  return nonEmpty;
}

// Random world boxes for a D-buffer: some inside the grid, some across its
// faces, some thin.
std::vector<WorldBox> randomBoxes(std::mt19937& rng, const Grid& g, int n) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Vec3 lo = g.minCorner(), ext = g.maxCorner() - g.minCorner();
  std::vector<WorldBox> boxes;
  for (int i = 0; i < n; ++i) {
    const Vec3 c = lo + Vec3(u(rng), u(rng), u(rng)) * ext * 1.1 - 0.05 * ext;
    Vec3 half = Vec3(0.05 + u(rng), 0.05 + u(rng), 0.05 + u(rng)) * ext * 0.3;
    if (i % 3 == 2) half[rng() % 3] = 0.2;  // a thin one
    boxes.push_back({c - half, c + half});
  }
  return boxes;
}

// ---------------------------------------------------------------------------

TEST(SamplerPartition, SampleAllOverCellPartitionsEqualsTheWhole) {
  std::mt19937 rng(5150);
  const Grid g = smallGrid();
  const Index3 cellDims = g.dims - Index3(1);
  int views = 0, eyeInsideViews = 0, nonEmptyParts = 0;
  for (int v = 0; v < 16 && views < 8; ++v) {
    const Projection proj = v % 2 ? Projection::Orthographic : Projection::Perspective;
    const bool eyeInside = v % 4 >= 2;
    SCOPED_TRACE("view " + std::to_string(v) + (eyeInside ? " (eye inside)" : ""));
    const ShadeBuffer shade = randomShade(g, rng);
    const EmptySpaceMap space(shade, 1);
    ASSERT_GT(space.emptyFraction(), 0.0);
    const Camera c = randomCamera(rng, g, proj, eyeInside, 45, 38);
    const SampleLattice lat(c, g, 0.45, 512, 1);
    // With and without a map passed in (sampleAll builds its own).
    const Sampler run{&shade, &lat, nullptr, v % 3 == 0 ? nullptr : &space};
    SamplerOptions whole;
    whole.tileSize = 8;
    const auto ref = run(1, whole);
    if (ref.size() < 500u) continue;  // a view of (almost) nothing: the next one
    ++views;
    eyeInsideViews += eyeInside;
    ASSERT_TRUE(sameBits(ref, run(2, whole)));
    const auto refSorted = sorted(ref);
    ASSERT_TRUE(noDuplicates(refSorted));
    for (int p = 0; p < 4; ++p) {
      SCOPED_TRACE("partition " + std::to_string(p));
      nonEmptyParts += checkPartition(run, refSorted, randomPartition(rng, cellDims, p % 2 == 0));
    }
    // The grid's own cells as one part, and one box around everything.
    checkPartition(run, refSorted, {Box3{Index3(0), cellDims}});
    checkPartition(run, refSorted, {Box3{Index3(-5), cellDims + Index3(7)}});
  }
  EXPECT_EQ(views, 8);
  EXPECT_GE(eyeInsideViews, 2);
  EXPECT_GT(nonEmptyParts, 8 * 4 * 2);
}

TEST(SamplerPartition, SampleRegionOverCellPartitionsEqualsTheWhole) {
  std::mt19937 rng(1991);
  const Grid g = smallGrid();
  const Index3 cellDims = g.dims - Index3(1);
  for (int v = 0; v < 6; ++v) {
    const Projection proj = v % 2 ? Projection::Orthographic : Projection::Perspective;
    const bool eyeInside = v >= 4;
    SCOPED_TRACE("view " + std::to_string(v) + (eyeInside ? " (eye inside)" : ""));
    const ShadeBuffer before = randomShade(g, rng);
    // The new shade: the old one with some balls more and some voxels cleared.
    ShadeBuffer shade = randomShade(g, rng, 2);
    for (std::uint64_t i = 0; i < g.voxelCount(); ++i)
      if (shade.at(i).a == 0 && rng() % 3 != 0) shade.at(i) = before.at(i);
    const EmptySpaceMap space(shade, 1), spaceBefore(before, 1);
    const Camera c = randomCamera(rng, g, proj, eyeInside, 40, 36);
    const SampleLattice lat(c, g, 0.5, 512, 1);
    DBuffer db;
    auto boxes = randomBoxes(rng, g, 2 + v % 4);
    // A stencil box of a random cell box too, as the pipeline builds them.
    const Box3 changed{Index3(rng() % 12, rng() % 10, rng() % 8),
                       Index3(12 + rng() % 15, 10 + rng() % 12, 8 + rng() % 11)};
    const auto sb = pp5::gp::stencilBoxes(g, std::span<const Box3>(&changed, 1));
    boxes.insert(boxes.end(), sb.begin(), sb.end());
    db.build(c, boxes);
    ASSERT_GT(db.touched().size(), 50u);
    for (int maps = 0; maps < 3; ++maps) {
      SCOPED_TRACE(maps == 0 ? "no map" : (maps == 1 ? "space" : "space and before"));
      const Sampler run{&shade, &lat, &db, maps >= 1 ? &space : nullptr, maps == 2 ? &spaceBefore : nullptr};
      SamplerOptions whole;
      whole.tileSize = 8;
      const auto ref = run(1, whole);
      ASSERT_GT(ref.size(), 200u);
      ASSERT_TRUE(sameBits(ref, run(2, whole)));
      const auto refSorted = sorted(ref);
      ASSERT_TRUE(noDuplicates(refSorted));
      for (int p = 0; p < 3; ++p) {
        SCOPED_TRACE("partition " + std::to_string(p));
        checkPartition(run, refSorted, randomPartition(rng, cellDims, p != 1));
      }
    }
  }
}

// Rays along the grid's axes, with sample points on cell faces: along two
// axes a ray's cell never changes (delta 0), and slabs of one cell must still
// split the samples exactly.
TEST(SamplerPartition, AxisAlignedRaysOnCellFacesSplitExactly) {
  Grid g;
  g.origin = Vec3(0.0);
  g.spacing = Vec3(1.0);
  g.dims = Index3(14, 12, 11);
  std::mt19937 rng(77);
  const ShadeBuffer shade = randomShade(g, rng, 4);
  const EmptySpaceMap space(shade, 1);
  const Index3 cellDims = g.dims - Index3(1);
  struct View {
    Vec3 eye, target, up;
  };
  const Vec3 centre = gridCentre(g);
  const std::vector<View> views = {
      {centre + Vec3(0, 0, 50), centre, Vec3(0, 1, 0)},
      {centre - Vec3(50, 0, 0), centre, Vec3(0, 0, 1)},
      {centre + Vec3(0, 50, 0), centre, Vec3(1, 0, 0)},
      {centre + Vec3(30, 30, 30), centre, Vec3(0, 0, 1)},  // through cell edges and corners
  };
  for (std::size_t vi = 0; vi < views.size(); ++vi) {
    SCOPED_TRACE("view " + std::to_string(vi));
    Camera c;
    c.projection = Projection::Orthographic;
    c.eye = views[vi].eye;
    c.target = views[vi].target;
    c.up = views[vi].up;
    c.width = c.height = 32;
    c.orthoHeightMm = 16.0;  // half-voxel pixels: ray centres on cell faces
    const SampleLattice lat(c, g, 0.5, 512, 1);
    DBuffer db;
    const std::vector<WorldBox> boxes = {{g.minCorner() + Vec3(1.0), g.maxCorner() - Vec3(2.0, 3.0, 1.0)}};
    db.build(c, boxes);
    for (int which = 0; which < 3; ++which) {
      const Sampler run{&shade, &lat, which == 0 ? nullptr : &db, which == 2 ? &space : nullptr};
      SamplerOptions whole;
      whole.tileSize = 8;
      const auto refSorted = sorted(run(1, whole));
      ASSERT_GT(refSorted.size(), 100u);
      for (int a = 0; a < 3; ++a) {
        // One slab per cell along axis a.
        std::vector<Box3> parts;
        for (std::int64_t i = 0; i < cellDims[a]; ++i) {
          Box3 b{Index3(0), cellDims};
          b.lo[a] = i;
          b.hi[a] = i + 1;
          parts.push_back(b);
        }
        checkPartition(run, refSorted, parts);
      }
    }
  }
}

// Samples whose float position (the sampler's) lies on the other side of a
// cell face than the exact line through the ray's base and step: an owner
// found by geometry alone would take them from the wrong GP. Found by search
// over a few views, then split by a cut at that face.
TEST(SamplerPartition, SamplesWithinRoundingOfACellFaceGoToTheirCell) {
  std::mt19937 rng(2718);
  const Grid g = smallGrid();
  const Index3 cellDims = g.dims - Index3(1);
  const ShadeBuffer shade = randomShade(g, rng, 6);
  const EmptySpaceMap space(shade, 1);
  int found = 0;
  for (int v = 0; v < 12 && found < 4; ++v) {
    SCOPED_TRACE("view " + std::to_string(v));
    const Camera c = randomCamera(rng, g, v % 2 ? Projection::Orthographic : Projection::Perspective, v == 2, 128, 128);
    const SampleLattice lat(c, g, 0.45, 512, 1);
    std::set<std::pair<int, std::int64_t>> faces;  // (axis, face) with a straddling sample
    for (std::uint32_t p = 0; p < lat.pixelCount(); ++p) {
      const pp5::VoxelRay vr = lat.voxelRay(p);
      for (std::uint32_t k = 0; k < lat.count(p); ++k) {
        const glm::vec3 pf = vr.at(k);
        for (int a = 0; a < 3; ++a) {
          const double q = static_cast<double>(vr.base[a]) + static_cast<double>(k) * static_cast<double>(vr.delta[a]);
          const auto cf = static_cast<std::int64_t>(std::floor(pf[a])), cq = static_cast<std::int64_t>(std::floor(q));
          const std::int64_t face = std::max(cf, cq);
          if (cf != cq && face >= 1 && face < cellDims[a]) faces.emplace(a, face);
        }
      }
    }
    found += static_cast<int>(faces.size());
    // Every sample of every ray: transparent ones too (no maps).
    DBuffer db;
    const std::vector<WorldBox> all = {{g.minCorner() - Vec3(1.0), g.maxCorner() + Vec3(1.0)}};
    db.build(c, all);
    for (int which = 0; which < 2; ++which) {
      const Sampler run{&shade, &lat, which == 0 ? &db : nullptr, which == 0 ? nullptr : &space};
      SamplerOptions whole;
      whole.tileSize = 8;
      const auto refSorted = sorted(run(2, whole));
      if (which == 0) {
        EXPECT_EQ(refSorted.size(), lat.totalSamples());
      }
      int n = 0;
      for (const auto& [a, face] : faces) {
        if (++n > 6) break;
        Box3 lo{Index3(0), cellDims}, hi{Index3(0), cellDims};
        lo.hi[a] = face;
        hi.lo[a] = face;
        checkPartition(run, refSorted, {lo, hi});
      }
    }
  }
  EXPECT_GT(found, 0) << "no sample within rounding of a face: the test needs another seed";
}

TEST(SamplerPartition, WorkTileMasksSelectTheirTilesPixels) {
  std::mt19937 rng(31337);
  const Grid g = smallGrid();
  for (int v = 0; v < 6; ++v) {
    const Projection proj = v % 2 ? Projection::Orthographic : Projection::Perspective;
    SCOPED_TRACE("view " + std::to_string(v));
    const ShadeBuffer shade = randomShade(g, rng);
    const EmptySpaceMap space(shade, 1);
    const int W = 37 + v, H = 29 + 2 * v;  // partial tiles on the right and at the bottom
    const Camera c = randomCamera(rng, g, proj, v == 4, W, H);
    const SampleLattice lat(c, g, 0.45, 512, 1);
    DBuffer db;
    auto boxes = randomBoxes(rng, g, 3);
    const Vec3 quarter = 0.25 * (g.maxCorner() - g.minCorner());
    boxes.push_back({gridCentre(g) - quarter, gridCentre(g) + quarter});
    db.build(c, boxes);
    const int tileSize = 5 + v % 4;
    const std::uint32_t tilesX = static_cast<std::uint32_t>((W + tileSize - 1) / tileSize);
    const std::uint32_t nTiles = pp5::gp::workTileCount(W, H, tileSize);
    ASSERT_EQ(nTiles, tilesX * static_cast<std::uint32_t>((H + tileSize - 1) / tileSize));
    auto tileOf = [&](std::uint32_t pixel) {
      return (pixel / static_cast<std::uint32_t>(W) / static_cast<std::uint32_t>(tileSize)) * tilesX +
             pixel % static_cast<std::uint32_t>(W) / static_cast<std::uint32_t>(tileSize);
    };
    for (int which = 0; which < 3; ++which) {
      SCOPED_TRACE(which == 0 ? "sampleAll" : (which == 1 ? "sampleRegion" : "sampleRegion with maps"));
      const Sampler run{&shade, &lat, which == 0 ? nullptr : &db, which == 2 ? &space : nullptr,
                    which == 2 ? &space : nullptr};
      SamplerOptions whole;
      whole.tileSize = tileSize;
      const auto ref = run(1, whole);
      ASSERT_GT(ref.size(), 200u);
      for (int m = 0; m < 4; ++m) {
        SamplerOptions opt = whole, rest = whole;
        opt.workTiles.resize(nTiles);
        rest.workTiles.resize(nTiles);
        const std::uint32_t keep = m == 0 ? 0u : (m == 3 ? 100u : 20u + rng() % 60u);  // percent
        for (std::uint32_t t = 0; t < nTiles; ++t) {
          opt.workTiles[t] = static_cast<std::uint8_t>(rng() % 100 < keep ? 1 + rng() % 255 : 0);
          rest.workTiles[t] = opt.workTiles[t] == 0;
        }
        // The unrestricted output filtered: SampleCollector orders by tile,
        // and a tile's samples in a fixed order, so not even the order changes.
        std::vector<RaySample> expected, expectedRest;
        for (const auto& s : ref) (opt.workTiles[tileOf(s.pixel)] ? expected : expectedRest).push_back(s);
        for (const int threads : {1, 2}) {
          std::mutex mu;
          std::set<std::uint32_t> tilesSeen;
          pp5::gp::SampleCollector col;
          pp5::gp::CallbackSink sink([&](int thread, std::uint32_t tile, std::span<const RaySample> s) {
            {
              std::lock_guard<std::mutex> lock(mu);
              tilesSeen.insert(tile);
            }
            col.consume(thread, tile, s);
          });
          if (run.dbuffer)
            pp5::gp::sampleRegion(shade, lat, db, settingsFor(threads), sink, run.space, opt, run.before);
          else
            pp5::gp::sampleAll(shade, lat, settingsFor(threads), sink, run.space, opt);
          const auto mine = col.samples();
          EXPECT_TRUE(sameBits(mine, expected)) << "mask " << m << ", threads " << threads;
          for (const auto t : tilesSeen) EXPECT_NE(opt.workTiles[t], 0) << "tile " << t << " is not selected";
          const auto others = run(threads, rest);
          EXPECT_TRUE(sameBits(others, expectedRest));
          std::vector<RaySample> both = mine;
          both.insert(both.end(), others.begin(), others.end());
          EXPECT_TRUE(sameBits(sorted(both), sorted(ref))) << "complementary masks do not give the whole";
        }
        // Both restrictions at once: a sample must pass both.
        SamplerOptions combined = opt;
        combined.ownedCells = Box3{Index3(3, 0, 2), Index3(15, 30, 12)};
        std::vector<RaySample> both;
        for (const auto& s : expected) {
          const Index3 cell = pp5::gp::stencilCell(lat, s.pixel, s.k);
          if (combined.ownedCells->contains(cell.x, cell.y, cell.z)) both.push_back(s);
        }
        EXPECT_TRUE(sameBits(run(2, combined), both)) << "mask " << m << " with owned cells";
      }
    }
  }
}

TEST(SamplerPartition, EmptySharesAndBadMasks) {
  std::mt19937 rng(4);
  const Grid g = smallGrid();
  const ShadeBuffer shade = randomShade(g, rng);
  const Camera c = randomCamera(rng, g, Projection::Perspective, false, 30, 20);
  const SampleLattice lat(c, g, 0.5, 512, 1);
  DBuffer db;
  db.build(c, randomBoxes(rng, g, 2));
  const Index3 cellDims = g.dims - Index3(1);
  for (const bool region : {false, true}) {
    const Sampler run{&shade, &lat, region ? &db : nullptr};
    ASSERT_FALSE(run(1).empty());
    for (const Box3& b : {Box3{Index3(-4, 0, 0), Index3(0, 5, 5)},                     // before the first cell
                          Box3{Index3(0, cellDims.y, 0), Index3(5, cellDims.y + 3, 5)},  // past the last
                          Box3{Index3(3, 4, 5), Index3(3, 9, 9)}}) {                     // no cells
      SamplerOptions opt;
      opt.ownedCells = b;
      EXPECT_TRUE(run(2, opt).empty()) << describe(b);
    }
    SamplerOptions none;
    none.tileSize = 8;
    none.workTiles.assign(pp5::gp::workTileCount(30, 20, 8), 0);
    EXPECT_TRUE(run(2, none).empty());
    SamplerOptions bad;
    bad.tileSize = 8;
    bad.workTiles.assign(pp5::gp::workTileCount(30, 20, 8) + 1, 1);
    EXPECT_THROW(run(1, bad), pp5::InvariantError);
  }
}

}  // namespace
