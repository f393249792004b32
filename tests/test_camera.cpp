#include <gtest/gtest.h>

#include <random>

#include "core/camera.hpp"

namespace {

pp5::Camera makeCamera(pp5::Projection p) {
  pp5::Camera c;
  c.projection = p;
  c.eye = {30.0, -40.0, 300.0};
  c.target = {5.0, 10.0, -20.0};
  c.up = {0.0, 1.0, 0.0};
  c.fovYDeg = 40.0;
  c.orthoHeightMm = 150.0;
  c.width = 320;
  c.height = 200;
  return c;
}

class CameraBoth : public ::testing::TestWithParam<pp5::Projection> {};

TEST_P(CameraBoth, TargetProjectsToImageCentre) {
  const auto c = makeCamera(GetParam());
  const auto p = c.project(c.target);
  ASSERT_TRUE(p);
  EXPECT_NEAR(p->px, 160.0, 1e-9);
  EXPECT_NEAR(p->py, 100.0, 1e-9);
  EXPECT_NEAR(p->depth, glm::length(c.target - c.eye), 1e-9);
}

TEST_P(CameraBoth, RayAndProjectAreInverse) {
  const auto c = makeCamera(GetParam());
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int i = 0; i < 200; ++i) {
    const double px = u(rng) * c.width, py = u(rng) * c.height, t = 10 + 500 * u(rng);
    const pp5::Ray r = c.ray(px, py);
    EXPECT_NEAR(glm::length(r.dir), 1.0, 1e-12);
    const auto p = c.project(r.origin + t * r.dir);
    ASSERT_TRUE(p);
    EXPECT_NEAR(p->px, px, 1e-7);
    EXPECT_NEAR(p->py, py, 1e-7);
  }
}

TEST_P(CameraBoth, ImageAxesPointRightAndUp) {
  const auto c = makeCamera(GetParam());
  const auto right = c.project(c.target + 10.0 * c.right());
  const auto up = c.project(c.target + 10.0 * c.trueUp());
  ASSERT_TRUE(right && up);
  EXPECT_GT(right->px, 160.0);
  EXPECT_NEAR(right->py, 100.0, 1e-9);
  EXPECT_LT(up->py, 100.0);  // row 0 is the top
}

INSTANTIATE_TEST_SUITE_P(Projections, CameraBoth,
                         ::testing::Values(pp5::Projection::Perspective, pp5::Projection::Orthographic));

TEST(Camera, KnownPointProjectsToExpectedPixel) {
  pp5::Camera c;
  c.eye = {0, 0, 100};
  c.target = {0, 0, 0};
  c.up = {0, 1, 0};
  c.width = c.height = 100;
  c.fovYDeg = 90.0;  // half-height at distance 100 is 100 mm
  const auto p = c.project({50.0, 0.0, 0.0});
  ASSERT_TRUE(p);
  EXPECT_NEAR(p->px, 75.0, 1e-9);
  EXPECT_NEAR(p->py, 50.0, 1e-9);
  EXPECT_FALSE(c.project({0, 0, 150}).has_value());  // behind the eye

  c.projection = pp5::Projection::Orthographic;
  c.orthoHeightMm = 200.0;
  const auto q = c.project({50.0, 50.0, -300.0});
  ASSERT_TRUE(q);
  EXPECT_NEAR(q->px, 75.0, 1e-9);
  EXPECT_NEAR(q->py, 25.0, 1e-9);
}

TEST(Camera, OrbitKeepsDistanceToTarget) {
  const auto c = makeCamera(pp5::Projection::Perspective);
  const auto o = c.orbited({0, 1, 0}, 90.0);
  EXPECT_NEAR(glm::length(o.eye - o.target), glm::length(c.eye - c.target), 1e-9);
  EXPECT_GT(glm::length(o.eye - c.eye), 1.0);
}

}  // namespace
