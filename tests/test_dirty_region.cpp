#include <gtest/gtest.h>

#include <random>

#include "reconstruction/dirty_region.hpp"

namespace {

pp5::Grid makeGrid(pp5::Index3 dims, double spacing = 1.0) {
  pp5::Grid g;
  g.origin = {-10.0, 4.0, 2.5};
  g.spacing = pp5::Vec3(spacing);
  g.dims = dims;
  return g;
}

TEST(DirtyRegion, BoxesMapToBricksAndBack) {
  const auto g = makeGrid({40, 33, 17});
  pp5::gp::DirtyRegion r(g, 16);
  EXPECT_EQ(r.brickDims(), pp5::Index3(3, 3, 2));
  r.addBox({{15, 0, 0}, {17, 1, 1}});  // straddles bricks 0 and 1 along x
  EXPECT_EQ(r.bricks().size(), 2u);
  EXPECT_TRUE(r.containsVoxel(0, 0, 0));
  EXPECT_TRUE(r.containsVoxel(31, 15, 15));
  EXPECT_FALSE(r.containsVoxel(32, 0, 0));
  // Edge bricks are clipped to the grid.
  r.addBox({{39, 32, 16}, {100, 100, 100}});
  EXPECT_EQ(r.brickBox(r.bricks().back()), (pp5::gp::Box3{{32, 32, 16}, {40, 33, 17}}));
  EXPECT_EQ(r.voxelCount(), 2u * 16 * 16 * 16 + 8u * 1 * 1);
  // Boxes outside the grid add nothing.
  const auto n = r.bricks().size();
  r.addBox({{-5, -5, -5}, {0, 10, 10}});
  EXPECT_EQ(r.bricks().size(), n);
}

TEST(DirtyRegion, GrowAndMerge) {
  const auto g = makeGrid({64, 64, 64});
  pp5::gp::DirtyRegion a(g, 16), b(g, 16);
  a.addBrick(1, 1, 1);
  const auto grown = a.grown(1);
  EXPECT_EQ(grown.bricks().size(), 27u);
  EXPECT_EQ(a.grown(0).bricks(), a.bricks());
  b.addBrick(3, 3, 3);
  b.merge(a);
  EXPECT_EQ(b.bricks().size(), 2u);
  EXPECT_EQ(b.bounds(), (pp5::gp::Box3{{16, 16, 16}, {64, 64, 64}}));
}

// Brute force: a voxel centre is inside the oriented slab.
bool insideSlab(const pp5::Vec3& p, const pp5::Vec3& o, const pp5::Vec3& u, const pp5::Vec3& v,
                const pp5::Vec3& reach) {
  const double lu = glm::length(u), lv = glm::length(v);
  const pp5::Vec3 n = glm::normalize(glm::cross(u, v));
  const pp5::Vec3 d = p - o;
  const double a = glm::dot(d, u / lu), b = glm::dot(d, v / lv), c = glm::dot(d, n);
  return a >= -reach.x && a <= lu + reach.x && b >= -reach.y && b <= lv + reach.y && std::abs(c) <= reach.z;
}

TEST(DirtyRegion, OrientedSlabCoversEveryVoxelInsideAndStaysThin) {
  const auto g = makeGrid({96, 96, 96}, 0.8);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    const pp5::Vec3 centre = g.voxelToWorld(pp5::Vec3(48.0)) + pp5::Vec3(U(rng), U(rng), U(rng)) * 20.0;
    pp5::Vec3 u = glm::normalize(pp5::Vec3(U(rng), U(rng), U(rng))) * 50.0;
    pp5::Vec3 v = glm::normalize(glm::cross(u, pp5::Vec3(U(rng), U(rng), U(rng)))) * 60.0;
    const pp5::Vec3 o = centre - 0.5 * u - 0.5 * v;
    const pp5::Vec3 reach(1.0, 0.75, 1.5);
    pp5::gp::DirtyRegion r(g, 8);
    pp5::gp::addOrientedSlab(r, o, u, v, reach);
    std::uint64_t inside = 0;
    for (std::int64_t k = 0; k < g.dims.z; ++k)
      for (std::int64_t j = 0; j < g.dims.y; ++j)
        for (std::int64_t i = 0; i < g.dims.x; ++i)
          if (insideSlab(g.voxelToWorld(pp5::Vec3(i, j, k)), o, u, v, reach)) {
            ++inside;
            ASSERT_TRUE(r.containsVoxel(i, j, k)) << "trial " << trial << " voxel " << i << "," << j << "," << k;
          }
    EXPECT_GT(inside, 0u);
    // A tilted 50x60 mm slice 3 mm thick must dirty a small part of a 77 mm cube.
    EXPECT_LT(r.voxelCount(), g.voxelCount() / 4) << "trial " << trial;
  }
}

}  // namespace
