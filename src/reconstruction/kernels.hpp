#pragma once
// The reconstruction methods ("kernels"), each as the rest of the system
// needs to know it: the stages outside reconstruction (the slab partition,
// the viewer's coverage, `evaluate`, the cost model) ask a method's entry
// here rather than testing its name. Each method defines its entry in its own
// file (reconstruction/splat_tent.cpp: tent; reconstruction/splat_pixel.cpp: nearest, trilinear);
// kernels.cpp lists them. Adding a method is its files, an enum value in
// reconstruction/reconstruction.hpp and one line in kernels.cpp.
#include <memory>
#include <span>
#include <string>
#include <string_view>

#include "reconstruction/reconstruction.hpp"

namespace pp5::gp {

struct Kernel {
  Method method;
  std::string_view name;     // recon.method's value
  std::string_view summary;  // one line, for messages and docs
  // The recon.* options it reads beyond those every method reads (the clip
  // rectangle, the fan, pixel rejection, threads).
  std::span<const std::string_view> options;
  // Bytes each voxel of its grid takes with these settings (the memory check).
  std::uint64_t (*bytesPerVoxel)(const ReconSettings&);
  std::unique_ptr<Reconstructor> (*make)(const Grid&, const ReconSettings&);
  // InputError for settings it cannot honour.
  void (*check)(const ReconSettings&);
  // A window of the grid grown to what its voxels depend on (setWindow).
  Box3 (*reach)(const Grid&, const ReconSettings&, const Box3& window);
  // Whether a frame's writes are bounded by the slice's reach
  // (reconstruction/slice_geometry.hpp), so that a slab GP out of reach gets the frame's
  // pose only and a window of the grid can be reconstructed alone.
  bool windowed;
  // Whether it reads the tent kernel's half-widths (recon.kernel_*_mm,
  // recon.kernel_from_frames), and so whether the cost model's work split,
  // fitted on them, applies.
  bool tentKernel;
  // The widest gap between neighbouring slices that it still fills, mm (the
  // viewer's coverage warns beyond it).
  double (*gapLimitMm)(const ReconSettings&, const Grid&);
  // E.g. "tent+fill-in" or "trilinear/mean".
  std::string (*describe)(const ReconSettings&);
};

// The entry of `m` (InvariantError for a value no method registered).
const Kernel& kernelFor(Method m);
// Every method, in recon.method's order.
std::span<const Kernel* const> kernels();

// The entries, each defined in its method's file.
extern const Kernel kTentKernel;
extern const Kernel kNearestKernel;
extern const Kernel kTrilinearKernel;

}  // namespace pp5::gp
