#pragma once
// A region of the world a frame reaches or a change covers: what the
// reconstruction reports (slice_geometry.hpp) and the D-buffer, the stencil
// and the partitions take.
#include "core/transform.hpp"

namespace pp5::gp {

// A closed axis-aligned box in world coordinates (mm).
struct WorldBox {
  Vec3 lo{0.0};
  Vec3 hi{0.0};
  bool empty() const { return hi.x < lo.x || hi.y < lo.y || hi.z < lo.z; }
};

}  // namespace pp5::gp
