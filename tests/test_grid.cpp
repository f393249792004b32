#include <gtest/gtest.h>

#include <limits>

#include "core/error.hpp"
#include "core/grid.hpp"

TEST(Grid, IndexingAndWorldMapping) {
  pp5::Grid g;
  g.origin = {-10.0, 5.0, 2.0};
  g.spacing = {0.5, 1.0, 2.0};
  g.dims = {4, 3, 2};
  EXPECT_EQ(g.voxelCount(), 24u);
  EXPECT_EQ(g.linear(1, 2, 1), static_cast<std::size_t>(1 + 4 * (2 + 3 * 1)));
  EXPECT_EQ(g.voxelToWorld({0, 0, 0}), g.origin);  // origin is the centre of voxel 0
  EXPECT_EQ(g.maxCorner(), pp5::Vec3(-8.5, 7.0, 4.0));
  EXPECT_EQ(g.worldToVoxel({-9.0, 6.0, 4.0}), pp5::Vec3(2.0, 1.0, 1.0));
  EXPECT_TRUE(g.contains(3, 2, 1));
  EXPECT_FALSE(g.contains(4, 0, 0));
  EXPECT_FALSE(g.contains(0, -1, 0));
}

TEST(Grid, MemoryEstimateSaturatesInsteadOfOverflowing) {
  pp5::Grid g;
  g.dims = {1 << 30, 1 << 30, 1 << 30};
  EXPECT_EQ(g.memoryBytes(4), std::numeric_limits<std::uint64_t>::max());
  g.dims = {256, 256, 256};
  EXPECT_EQ(g.memoryBytes(4), 256ull * 256 * 256 * 4);
}

TEST(Grid, HugeGridIsRefusedBeforeAllocation) {
  // The PLUS user's setting: 397 billion voxels.
  pp5::Grid g;
  g.spacing = {0.01, 0.01, 0.01};
  g.dims = {7350, 7350, 7350};
  try {
    pp5::checkGridFits(g, 4, "recon.toml");
    FAIL() << "a 397-billion-voxel grid was accepted";
  } catch (const pp5::InputError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("recon.toml"), std::string::npos) << m;
    EXPECT_NE(m.find("7350x7350x7350"), std::string::npos) << m;
    EXPECT_NE(m.find("GiB"), std::string::npos) << m;
  }
}

TEST(Grid, LimitAndInvalidGridsAreChecked) {
  pp5::Grid g;
  g.dims = {100, 100, 100};
  EXPECT_NO_THROW(pp5::checkGridFits(g, 4, "x", 4'000'000));
  EXPECT_THROW(pp5::checkGridFits(g, 4, "x", 3'999'999), pp5::InputError);
  g.spacing = {1.0, 0.0, 1.0};
  EXPECT_THROW(pp5::checkGridFits(g, 1, "x", 1ull << 40), pp5::InputError);
  g.spacing = {1.0, 1.0, 1.0};
  g.dims = {0, 10, 10};
  EXPECT_THROW(pp5::checkGridFits(g, 1, "x", 1ull << 40), pp5::InputError);
  EXPECT_GT(pp5::availableMemoryBytes(), 0u);
}
