// The registry's entry (reconstruction/kernels.hpp) of the 1990 paper's tent kernel (reconstruction/splat_tent.cpp).
#include <algorithm>
#include <string>

#include <fmt/format.h>

#include "core/error.hpp"
#include "reconstruction/kernels.hpp"
#include "reconstruction/splat_tent.hpp"

namespace pp5::gp {

namespace {

constexpr std::string_view kTentOptions[] = {
    "recon.kernel_lateral_mm", "recon.kernel_axial_mm",     "recon.kernel_elevation_mm",
    "recon.kernel_from_frames", "recon.fill_in",            "recon.fill_in_max_gap_mm",
    "recon.fill_in_max_angle_deg", "recon.replacement",     "recon.motion_vector_new_weight",
    "recon.motion_vector_brick", "recon.decay_tau_s"};

void checkTent(const ReconSettings& s) {
  // PLUS's hole filling weighs the neighbours by the per-voxel weights of
  // nearest and trilinear splatting; the tent kernel keeps no such weights
  // and fills between slices itself (recon.fill_in). Silently ignoring the
  // option would leave a user believing the holes were filled.
  if (s.pixel.fillHoles || s.pixel.fillHolesIncremental || !s.pixel.holeFilling.empty())
    throw InputError(
        "recon.fill_holes (and fill_holes_incremental, or a PLUS HoleFilling element) works with recon.method = "
        "nearest or trilinear, whose per-voxel weights it needs; the tent method fills between slices itself "
        "(recon.fill_in, recon.fill_in_max_gap_mm): set recon.method = trilinear for PLUS's hole filling, or "
        "recon.fill_holes = false");
  // PLUS's fixed point is how PLUS splats pixels; the tent kernel has no PLUS
  // counterpart and always computes in float.
  if (s.arithmetic == Arithmetic::Plus)
    throw InputError("recon.arithmetic = \"plus\" reproduces PLUS's nearest and trilinear splatting; the tent method "
                     "computes in float: set recon.method = nearest or trilinear, or recon.arithmetic = \"float\"");
}

// A motion-vector cell is replaced whole: a window takes whole cells.
Box3 tentReach(const Grid&, const ReconSettings& s, const Box3& window) {
  Box3 w = window;
  if (s.tent.replacement == Replacement::MotionVector) {
    const std::int64_t b = std::max(1, s.tent.motionVectorBrick);
    w.lo = w.lo / Index3(b) * Index3(b);  // lo >= 0: division rounds down
    w.hi = (w.hi + Index3(b - 1)) / Index3(b) * Index3(b);
  }
  return w;
}

// Fill-in bridges gaps up to its limit; without it the kernel's elevation reach does.
double tentGapLimitMm(const ReconSettings& s, const Grid&) {
  return s.tent.fillIn ? s.tent.fillInMaxGapMm : 2.0 * s.tent.kernelElevationMm;
}

std::string describeTent(const ReconSettings& s) { return s.tent.fillIn ? "tent+fill-in" : "tent"; }

}  // namespace

const Kernel kTentKernel = {Method::Tent,
                            "tent",
                            "Ohbuchi & Fuchs 1990: an asymmetric tent kernel that rotates with the slice, "
                            "inter-slice fill-in, replacement of aging data",
                            kTentOptions,
                            tentBytesPerVoxel,
                            makeTentReconstructor,
                            checkTent,
                            tentReach,
                            /*windowed=*/true,
                            /*tentKernel=*/true,
                            tentGapLimitMm,
                            describeTent};

}  // namespace pp5::gp
