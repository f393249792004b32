#include "core/camera.hpp"

#include <cmath>

#include <glm/gtc/constants.hpp>

#include "core/error.hpp"

namespace pp5 {

Vec3 Camera::forward() const { return glm::normalize(target - eye); }
Vec3 Camera::right() const { return glm::normalize(glm::cross(forward(), up)); }
Vec3 Camera::trueUp() const { return glm::cross(right(), forward()); }

namespace {
// Half-height of the image plane at unit distance (perspective) or in mm (ortho).
double halfHeight(const Camera& c) {
  return c.projection == Projection::Perspective ? std::tan(glm::radians(c.fovYDeg) * 0.5) : c.orthoHeightMm * 0.5;
}
}  // namespace

Ray Camera::ray(double px, double py) const {
  PP5_CHECK_GT(width, 0);
  PP5_CHECK_GT(height, 0);
  const double h = halfHeight(*this);
  const double w = h * static_cast<double>(width) / static_cast<double>(height);
  // Normalised screen coordinates in [-1, 1]; y grows upwards.
  const double sx = (2.0 * px / width - 1.0) * w;
  const double sy = (1.0 - 2.0 * py / height) * h;
  const Vec3 f = forward(), r = right(), u = trueUp();
  if (projection == Projection::Perspective) return {eye, glm::normalize(f + sx * r + sy * u)};
  return {eye + sx * r + sy * u, f};
}

std::optional<Camera::Projected> Camera::project(const Vec3& world) const {
  const Vec3 f = forward(), r = right(), u = trueUp();
  const Vec3 d = world - eye;
  const double depth = glm::dot(d, f);
  const double h = halfHeight(*this);
  const double w = h * static_cast<double>(width) / static_cast<double>(height);
  double sx = glm::dot(d, r), sy = glm::dot(d, u);
  if (projection == Projection::Perspective) {
    if (depth <= 0.0) return std::nullopt;
    sx /= depth;
    sy /= depth;
  }
  const double px = (sx / w + 1.0) * 0.5 * width;
  const double py = (1.0 - sy / h) * 0.5 * height;
  return Projected{px, py, depth};
}

Camera Camera::orbited(const Vec3& axis, double degrees) const {
  Camera c = *this;
  const Mat4 rot = rotationAxisAngle(axis, glm::radians(degrees));
  c.eye = target + transformVector(rot, eye - target);
  c.up = transformVector(rot, up);
  return c;
}

}  // namespace pp5
