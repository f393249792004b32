// The registry's entry (reconstruction/kernels.hpp) of PLUS's pixel methods, nearest and trilinear (reconstruction/splat_pixel.cpp).
#include <algorithm>
#include <string>

#include <fmt/format.h>

#include "core/error.hpp"
#include "reconstruction/kernels.hpp"
#include "reconstruction/splat_pixel.hpp"
#include "reconstruction/hole_fill.hpp"

namespace pp5::gp {

namespace {

constexpr std::string_view kPixelOptions[] = {"recon.compounding", "recon.arithmetic", "recon.fill_holes",
                                              "recon.fill_holes_incremental"};

void checkPixel(const ReconSettings& s) {
  if (s.tent.kernelFromFrames)
    throw InputError(fmt::format("recon.kernel_from_frames derives the tent kernel, but recon.method is '{}': use it "
                                 "with recon.method = \"tent\"", enumName(s.method)));
}

// Hole filling reads the voxels around a hole.
Box3 pixelReach(const Grid&, const ReconSettings& s, const Box3& window) {
  if (!s.pixel.fillHoles) return window;
  const HoleFiller filler(s.pixel.holeFilling.empty() ? HoleFiller::defaultElements() : s.pixel.holeFilling,
                          s.arithmetic == Arithmetic::Plus);
  return window.grown(filler.reach());
}

// A pixel reaches the voxels next to its slice; hole filling is a later pass.
double pixelGapLimitMm(const ReconSettings&, const Grid& g) {
  return 2.0 * std::max(g.spacing.x, std::max(g.spacing.y, g.spacing.z));
}

std::string describePixel(const ReconSettings& s) {
  return std::string(enumName(s.method)) + "/" + std::string(enumName(s.pixel.compounding));
}

}  // namespace

// Nearest and trilinear differ only inside the splatting (reconstruction/splat_pixel.cpp).
constexpr Kernel pixelKernel(Method m, std::string_view name, std::string_view summary) {
  return {m,          name,       summary,   kPixelOptions, pixelBytesPerVoxel, makePixelReconstructor, checkPixel,
          pixelReach, /*windowed=*/false, /*tentKernel=*/false, pixelGapLimitMm, describePixel};
}

const Kernel kNearestKernel =
    pixelKernel(Method::Nearest, "nearest", "PLUS's pixel nearest-neighbour splatting (MEAN, LATEST or MAXIMUM compounding)");
const Kernel kTrilinearKernel =
    pixelKernel(Method::Trilinear, "trilinear", "PLUS's pixel trilinear splatting (MEAN, LATEST or MAXIMUM compounding)");

}  // namespace pp5::gp
