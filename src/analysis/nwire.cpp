#include "analysis/nwire.hpp"

#include <cmath>

#include <Eigen/Dense>

#include "core/error.hpp"

namespace pp5::calib {

double ratioAlong(const Vec2& a, const Vec2& b, const Vec2& c) {
  const Vec2 ac = c - a;
  const double len2 = glm::dot(ac, ac);
  PP5_CHECK(len2 > 0.0);
  return glm::dot(b - a, ac) / len2;
}

NWirePhantom::NWirePhantom(std::vector<PlusNWirePattern> patterns) : patterns_(std::move(patterns)) {
  PP5_CHECK(!patterns_.empty());
  for (const auto& p : patterns_) {
    const glm::dvec3 d = glm::normalize(p.wires[0].back - p.wires[0].front);
    const glm::dvec3 across = p.wires[2].front - p.wires[0].front;
    spacing_.push_back(glm::length(across - glm::dot(across, d) * d));
  }
  for (std::size_t k = 0; k + 1 < patterns_.size(); ++k) {
    const auto& p = patterns_[k];
    const glm::dvec3 n = glm::normalize(
        glm::cross(p.wires[0].back - p.wires[0].front, p.wires[2].front - p.wires[0].front));
    planeGap_.push_back(std::abs(glm::dot(patterns_[k + 1].wires[0].front - p.wires[0].front, n)));
  }
}

glm::dvec3 NWirePhantom::wirePoint(int k, int w) const { return pattern(k).wires[static_cast<std::size_t>(w)].front; }

glm::dvec3 NWirePhantom::wireDirection(int k, int w) const {
  const auto& wire = pattern(k).wires[static_cast<std::size_t>(w)];
  return glm::normalize(wire.back - wire.front);
}

glm::dvec3 NWirePhantom::middleWirePoint(int k, double u) const {
  // The image plane meets the pattern's plane in a line through X0 (on wire 0),
  // X1 (on the middle wire) and X2 (on wire 2), with X1 = (1-u) X0 + u X2. With
  // X0 = A + s0 d, X2 = C + s2 d (the outer wires share d) and X1 = B + s1 e:
  //   s1 e - m d = (1-u) A + u C - B,  m = (1-u) s0 + u s2,
  // two unknowns in the pattern's plane: least squares over the three axes.
  const auto& p = pattern(k);
  const glm::dvec3 A = p.wires[0].front, B = p.wires[1].front, C = p.wires[2].front;
  const glm::dvec3 d = wireDirection(k, 0), e = wireDirection(k, 1);
  const glm::dvec3 rhs = (1.0 - u) * A + u * C - B;
  Eigen::Matrix<double, 3, 2> M;
  M << e.x, -d.x, e.y, -d.y, e.z, -d.z;
  const Eigen::Vector3d r(rhs.x, rhs.y, rhs.z);
  const Eigen::Vector2d s = M.colPivHouseholderQr().solve(r);
  return B + s[0] * e;
}

}  // namespace pp5::calib
