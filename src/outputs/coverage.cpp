#include "outputs/coverage.hpp"

#include <algorithm>
#include <cmath>

#include "reconstruction/kernels.hpp"
#include "core/error.hpp"

namespace pp5::host {

std::array<Vec3, 4> frameCorners(const Mat4& m, int w, int h) {
  const double x1 = std::max(0, w - 1), y1 = std::max(0, h - 1);
  return {transformPoint(m, Vec3(0, 0, 0)), transformPoint(m, Vec3(x1, 0, 0)), transformPoint(m, Vec3(x1, y1, 0)),
          transformPoint(m, Vec3(0, y1, 0))};
}

std::optional<std::array<std::array<double, 2>, 4>> outlineOnScreen(const Camera& camera,
                                                                     const std::array<Vec3, 4>& corners) {
  std::array<std::array<double, 2>, 4> out{};
  for (int i = 0; i < 4; ++i) {
    const auto p = camera.project(corners[static_cast<std::size_t>(i)]);
    if (!p) return std::nullopt;
    out[static_cast<std::size_t>(i)] = {p->px, p->py};
  }
  return out;
}

Coverage::Coverage(const Grid& grid, const gp::ReconSettings& recon, double cellMm) : grid_(grid) {
  const double finest = std::min(grid.spacing.x, std::min(grid.spacing.y, grid.spacing.z));
  cellMm_ = std::max(cellMm, finest);
  limitMm_ = gp::kernelFor(recon.method).gapLimitMm(recon, grid);
  for (int a = 0; a < 3; ++a)
    cells_[static_cast<std::size_t>(a)] =
        std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil(grid.dims[a] * grid.spacing[a] / cellMm_)));
  hit_.assign(static_cast<std::size_t>(cells_[0] * cells_[1] * cells_[2]), 0);
}

void Coverage::add(const Mat4& m, int w, int h) {
  ++frames_;
  const auto corners = frameCorners(m, w, h);
  if (prevCorners_) {
    gapMm_ = 0.0;
    for (std::size_t i = 0; i < 4; ++i) gapMm_ = std::max(gapMm_, glm::length(corners[i] - (*prevCorners_)[i]));
  }
  prevCorners_ = corners;
  // Walk the image plane at half a cell, in pixels along each image axis.
  const Vec3 ex = transformVector(m, Vec3(1, 0, 0)), ey = transformVector(m, Vec3(0, 1, 0));
  const double lx = glm::length(ex), ly = glm::length(ey);
  if (!(lx > 0.0) || !(ly > 0.0) || w <= 0 || h <= 0) return;
  const double sx = std::max(0.25, 0.5 * cellMm_ / lx), sy = std::max(0.25, 0.5 * cellMm_ / ly);
  const Vec3 lo = grid_.voxelToWorld(Vec3(-0.5));
  for (double y = 0.0; y <= h - 1 + 1e-9; y += sy)
    for (double x = 0.0; x <= w - 1 + 1e-9; x += sx) {
      const Vec3 p = transformPoint(m, Vec3(x, y, 0)) - lo;
      std::int64_t c[3];
      bool inside = true;
      for (int a = 0; a < 3; ++a) {
        c[a] = static_cast<std::int64_t>(std::floor(p[a] / cellMm_));
        inside = inside && c[a] >= 0 && c[a] < cells_[static_cast<std::size_t>(a)];
      }
      if (!inside) continue;
      std::uint8_t& hv = hit_[static_cast<std::size_t>((c[2] * cells_[1] + c[1]) * cells_[0] + c[0])];
      if (!hv) {
        hv = 1;
        ++hits_;
      }
    }
}

double Coverage::fraction() const { return hit_.empty() ? 0.0 : static_cast<double>(hits_) / static_cast<double>(hit_.size()); }

bool Coverage::covered(const Vec3& world) const {
  const Vec3 p = world - grid_.voxelToWorld(Vec3(-0.5));
  std::int64_t c[3];
  for (int a = 0; a < 3; ++a) {
    c[a] = static_cast<std::int64_t>(std::floor(p[a] / cellMm_));
    if (c[a] < 0 || c[a] >= cells_[static_cast<std::size_t>(a)]) return false;
  }
  return hit_[static_cast<std::size_t>((c[2] * cells_[1] + c[1]) * cells_[0] + c[0])] != 0;
}

}  // namespace pp5::host
