#pragma once
// A pinhole (perspective) or orthographic camera with its image size.
// Pixel (px, py) covers [px, px+1) x [py, py+1); its ray passes through the
// centre (px + 0.5, py + 0.5). Row 0 is the top of the image.
#include <optional>

#include "core/transform.hpp"
#include "core/enum_names.hpp"

namespace pp5 {

enum class Projection { Perspective, Orthographic };

struct Ray {
  Vec3 origin;
  Vec3 dir;  // unit length
};

struct Camera {
  Projection projection = Projection::Perspective;
  Vec3 eye{0.0, 0.0, 500.0};
  Vec3 target{0.0};
  Vec3 up{0.0, 1.0, 0.0};
  double fovYDeg = 30.0;       // perspective: full vertical field of view
  double orthoHeightMm = 200;  // orthographic: height of the view in mm
  int width = 512;
  int height = 512;
  bool operator==(const Camera&) const = default;  // the same view, field by field

  // Right-handed camera basis: right, true up, and forward (towards target).
  Vec3 forward() const;
  Vec3 right() const;
  Vec3 trueUp() const;

  Ray ray(double px, double py) const;  // continuous pixel coordinates
  Ray pixelRay(int x, int y) const { return ray(x + 0.5, y + 0.5); }
  // Continuous pixel coordinates of a world point, and its depth along
  // forward(); nullopt for points at or behind the eye (perspective).
  struct Projected {
    double px, py, depth;
  };
  std::optional<Projected> project(const Vec3& world) const;

  // Orbit: the eye rotated about the target by `degrees` around `axis`.
  Camera orbited(const Vec3& axis, double degrees) const;
};

}  // namespace pp5

namespace pp5 {

template <>
struct EnumNames<Projection> {
  static constexpr std::string_view key = "render.projection";
  static constexpr std::array<std::pair<Projection, std::string_view>, 2> names{{
      {Projection::Perspective, "perspective"},
      {Projection::Orthographic, "orthographic"}}};
};

}  // namespace pp5
