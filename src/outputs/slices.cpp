#include "outputs/slices.hpp"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/error.hpp"
#include "formats/image_io.hpp"
#include "outputs/coverage.hpp"

namespace pp5::host {

namespace {

// The plane's in-plane axes (image right, image up) and normal, as grid axes.
struct Axes {
  int right, up, normal;
};
Axes axesOf(SliceAxis a) {
  switch (a) {
    case SliceAxis::Axial: return {0, 1, 2};
    case SliceAxis::Coronal: return {0, 2, 1};
    case SliceAxis::Sagittal: return {1, 2, 0};
  }
  throw InvariantError("slice: unknown axis");
}

// Trilinear value at continuous voxel coordinates; nullopt outside the grid's voxel centres' box.
bool trilinear(const Volume& v, const Vec3& p, double& out) {
  const Grid& g = v.grid;
  std::int64_t i0[3];
  double f[3];
  for (int a = 0; a < 3; ++a) {
    if (!(p[a] >= -0.5) || !(p[a] <= g.dims[a] - 0.5)) return false;
    const double c = std::clamp(p[a], 0.0, static_cast<double>(g.dims[a] - 1));
    i0[a] = std::min<std::int64_t>(static_cast<std::int64_t>(c), std::max<std::int64_t>(0, g.dims[a] - 2));
    f[a] = g.dims[a] > 1 ? c - static_cast<double>(i0[a]) : 0.0;
  }
  double acc = 0.0;
  for (int k = 0; k < 8; ++k) {
    const std::int64_t x = std::min(i0[0] + (k & 1), g.dims.x - 1), y = std::min(i0[1] + ((k >> 1) & 1), g.dims.y - 1),
                       z = std::min(i0[2] + ((k >> 2) & 1), g.dims.z - 1);
    const double w = ((k & 1) ? f[0] : 1 - f[0]) * (((k >> 1) & 1) ? f[1] : 1 - f[1]) * (((k >> 2) & 1) ? f[2] : 1 - f[2]);
    if (w != 0.0) acc += w * v.value(g.linear(x, y, z));
  }
  out = acc;
  return true;
}

}  // namespace

std::string_view sliceName(SliceAxis a) {
  switch (a) {
    case SliceAxis::Axial: return "axial";
    case SliceAxis::Coronal: return "coronal";
    case SliceAxis::Sagittal: return "sagittal";
  }
  return "?";
}

SliceImage slice(const Volume& v, const SlicePlane& plane, const SliceLook& look, const Coverage* coverage) {
  if (!(look.window > 0.0) || !std::isfinite(look.window) || !std::isfinite(look.level))
    throw InputError(fmt::format("slice: window {} and level {}: the window must be > 0", look.window, look.level));
  if (look.longSide < 8 || look.longSide > 8192)
    throw InputError(fmt::format("slice: {} pixels on the long side: use 8 to 8192", look.longSide));
  const Grid& g = v.grid;
  const Axes ax = axesOf(plane.axis);
  const Vec3 lo = g.voxelToWorld(Vec3(-0.5)), hi = g.voxelToWorld(Vec3(g.dims) - Vec3(0.5));
  const double extR = hi[ax.right] - lo[ax.right], extU = hi[ax.up] - lo[ax.up];
  const double pitch = std::max(extR, extU) / look.longSide;  // mm per pixel
  SliceImage im;
  im.width = std::max(1, static_cast<int>(std::lround(extR / pitch)));
  im.height = std::max(1, static_cast<int>(std::lround(extU / pitch)));
  im.rgb.assign(static_cast<std::size_t>(im.width) * static_cast<std::size_t>(im.height) * 3, 0);
  Vec3 right(0.0), up(0.0), normal(0.0);
  right[ax.right] = 1.0;
  up[ax.up] = 1.0;
  normal[ax.normal] = 1.0;
  const double t = glm::radians(plane.tiltDeg);
  const Vec3 upT = std::cos(t) * up + std::sin(t) * normal;  // oblique: up tilted towards the normal
  Vec3 centre = 0.5 * (lo + hi);
  centre[ax.normal] = lo[ax.normal] + std::clamp(plane.position, 0.0, 1.0) * (hi[ax.normal] - lo[ax.normal]);
  const double black = look.level - 0.5 * look.window;
  for (int y = 0; y < im.height; ++y)
    for (int x = 0; x < im.width; ++x) {
      const Vec3 p = centre + ((x + 0.5) - 0.5 * im.width) * pitch * right + (0.5 * im.height - (y + 0.5)) * pitch * upT;
      double val = 0.0;
      if (!trilinear(v, g.worldToVoxel(p), val)) continue;
      const double grey = 255.0 * std::clamp((val - black) / look.window, 0.0, 1.0);
      std::uint8_t* px = &im.rgb[(static_cast<std::size_t>(y) * static_cast<std::size_t>(im.width) + x) * 3];
      if (coverage && !coverage->covered(p)) {  // not swept yet: dimmed towards dark red
        px[0] = static_cast<std::uint8_t>(std::lround(0.5 * grey + 70.0));
        px[1] = px[2] = static_cast<std::uint8_t>(std::lround(0.5 * grey));
      } else {
        px[0] = px[1] = px[2] = static_cast<std::uint8_t>(std::lround(grey));
      }
    }
  return im;
}

std::vector<std::string> writeMpr(const Volume& v, const SliceLook& look, const std::string& stem) {
  std::vector<std::string> paths;
  for (const SliceAxis a : {SliceAxis::Axial, SliceAxis::Coronal, SliceAxis::Sagittal}) {
    const SliceImage im = slice(v, SlicePlane{a, 0.5, 0.0}, look);
    std::vector<std::uint8_t> grey(static_cast<std::size_t>(im.width) * static_cast<std::size_t>(im.height));
    for (std::size_t i = 0; i < grey.size(); ++i) grey[i] = im.rgb[3 * i];
    paths.push_back(fmt::format("{}_{}.png", stem, sliceName(a)));
    writeGrayPng(paths.back(), im.width, im.height, grey.data());
  }
  return paths;
}

}  // namespace pp5::host
