#pragma once
// The geometry of an N-wire phantom (PLUS's multi-N, as fCal uses it): where
// the image plane cuts each pattern's diagonal wire follows from the three dots'
// spacing in the image alone, whatever the calibration.
#include <array>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "formats/plus_config.hpp"

namespace pp5::calib {

using Vec2 = glm::dvec2;

// The dots of one pattern in one image, labelled by wire: dot[w] is where the
// image shows wire w of the pattern (PhantomDefinition order), in pixels
// (x = column, y = row).
using PatternDots = std::array<Vec2, 3>;

// Where b lies along a -> c: the projection of b - a on c - a over |c - a|^2
// (0 at a, 1 at c). Affine maps keep this ratio, so it is the same in the image
// and on the image plane in mm.
double ratioAlong(const Vec2& a, const Vec2& b, const Vec2& c);

class NWirePhantom {
public:
  // The patterns must be N-wires (core's reader checks that).
  explicit NWirePhantom(std::vector<PlusNWirePattern> patterns);

  int patternCount() const { return static_cast<int>(patterns_.size()); }
  const PlusNWirePattern& pattern(int k) const { return patterns_[static_cast<std::size_t>(k)]; }
  // Distance between the outer wires of pattern k (mm): the length of its
  // dots' line in an image plane square to the wires.
  double outerSpacingMm(int k) const { return spacing_[static_cast<std::size_t>(k)]; }
  // Distance between the planes of patterns k and k + 1 (mm).
  double planeDistanceMm(int k) const { return planeGap_[static_cast<std::size_t>(k)]; }
  // The point, in Phantom mm, where a plane that shows pattern k's wire 0 at
  // image point a, wire 1 at b and wire 2 at c cuts the middle wire: u =
  // ratioAlong(a, b, c) places it between the outer wires, and the middle
  // wire's slant across the pattern gives where along the wires that is.
  glm::dvec3 middleWirePoint(int k, double u) const;
  // Wire w of pattern k as a point and a unit direction (Phantom mm).
  glm::dvec3 wirePoint(int k, int w) const;
  glm::dvec3 wireDirection(int k, int w) const;

private:
  std::vector<PlusNWirePattern> patterns_;
  std::vector<double> spacing_, planeGap_;
};

}  // namespace pp5::calib
