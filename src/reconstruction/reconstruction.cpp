#include "reconstruction/reconstruction.hpp"
#include "core/threads.hpp"
#include "reconstruction/kernels.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/config.hpp"
#include "core/error.hpp"
#include "reconstruction/hole_fill.hpp"
#include "reconstruction/splat_pixel.hpp"
#include "reconstruction/splat_tent.hpp"

namespace pp5::gp {

void registerOptions(ConfigSchema& schema, ReconSettings& s) {
  schema.section("recon", "Incremental reconstruction of each frame into the grid (`reconstruct`, the GP stage).");
  enumOption(schema, "recon.method", &s.method, Method::Tent,
                "`tent`: the 1990 paper's forward mapping with an asymmetric tent kernel, fill-in and "
                "replacement; `nearest` / `trilinear`: PLUS's pixel nearest neighbour and trilinear splatting.");
  enumOption(schema, "recon.compounding", &s.pixel.compounding, Compounding::Mean,
                "How `nearest` and `trilinear` combine several hits on a voxel (PLUS's CompoundingMode).");
  enumOption(schema, "recon.arithmetic", &s.arithmetic, Arithmetic::Float,
                "`float`: exact weighted means in float accumulators; `plus`: PLUS's 14-bit fixed point, "
                "truncating 8-bit running mean and 16-bit accumulator, to reproduce PLUS bit for bit (nearest and "
                "trilinear only; the tent method refuses it).");
  schema.option("recon.threads", &s.threads, 0, 0, kMaxThreads,
                "Threads; 0 = every core. The result does not depend on it. Under mpirun, parallel.threads replaces it.");
  schema.option("recon.skip_interval", &s.skipInterval, 1, 1, 100000,
                "Insert every n-th frame (PLUS's SkipInterval; `reconstruct` and `evaluate truth`: `run` refuses a "
                "value above 1 and thins frames with run.capture_interval_mm instead).");
  // The defaults match the default probe's resolution cell (paper35: lateral
  // FWHM 1.8 mm, elevation FWHM 4 mm, pulse about 1 mm): averaging over one
  // cell removes speckle without blurring what the scanner resolves
  // (docs/quality.md measures the choice).
  schema.option("recon.kernel_lateral_mm", &s.tent.kernelLateralMm, 2.0, 0.01, 50.0,
                "Tent kernel half-width along the slice's lateral axis (image x), mm. About the probe's lateral "
                "resolution (FWHM); the default suits the `paper35` probe.");
  schema.option("recon.kernel_axial_mm", &s.tent.kernelAxialMm, 1.0, 0.01, 50.0,
                "Tent kernel half-width along the slice's axial axis (image y, depth), mm. About the pulse length.");
  schema.option("recon.kernel_elevation_mm", &s.tent.kernelElevationMm, 3.0, 0.01, 50.0,
                "Tent kernel half-width across the slice (elevation), mm. About the elevation beam width (FWHM) "
                "less a little; when consecutive slices are farther apart than this reaches, fill-in interpolates.");
  schema.option("recon.kernel_from_frames", &s.tent.kernelFromFrames, false,
                "Derive the tent kernel from the frames (`reconstruct`, `evaluate`, and `run` with run.source = "
                "\"sequence\" or the simulator's cached sweep; a live source or run.simulate_live cannot be looked "
                "ahead in, and `run` refuses it there): "
                "twice the speckle's lateral and axial half widths (as `evaluate speckle` measures them; at least twice "
                "the pixel inserted, after run.subsample) and 1.5 times "
                "the median spacing of the frames that are inserted. A kernel half-width set in the file or with --set "
                "wins over the derived one. Printed before the reconstruction; `run` writes it to settings.toml.");
  schema.option("recon.fill_in", &s.tent.fillIn, true,
                "Interpolate intermediate slices between consecutive frames that are farther apart than the "
                "kernel reaches (tent method).");
  schema.option("recon.fill_in_max_gap_mm", &s.tent.fillInMaxGapMm, 12.0, 0.0, 1000.0,
                "No fill-in across a larger displacement of any image corner (the probe jumped), mm.");
  schema.option("recon.fill_in_max_angle_deg", &s.tent.fillInMaxAngleDeg, 20.0, 0.0, 180.0,
                "No fill-in across a larger rotation between consecutive frames, degrees.");
  enumOption(schema, "recon.replacement", &s.tent.replacement, Replacement::Accumulate,
                "Replacement of aging data when a region is scanned again (tent method): plain accumulation, "
                "the paper's motion vectors, or exponential decay.");
  schema.option("recon.motion_vector_new_weight", &s.tent.motionVectorNewWeight, 0.8, 0.5, 1.0,
                "Motion vectors: share of the new sweep in a voxel re-scanned from the opposite direction.");
  schema.option("recon.motion_vector_brick", &s.tent.motionVectorBrick, 8, 1, 256,
                "Motion vectors: voxels per side of the cell that remembers its last sweep direction.");
  schema.option("recon.decay_tau_s", &s.tent.decayTauS, 5.0, 0.01, 1e6,
                "Decay: time constant tau of the fading of old contributions, seconds.");
  schema.option("recon.clip_origin", &s.clipOrigin, {0, 0}, 0, 100000, "Clip rectangle origin, pixels.");
  schema.option("recon.clip_size", &s.clipSize, {0, 0}, 0, 100000, "Clip rectangle size, pixels; 0 0 = whole frame.");
  schema.option("recon.fan_angles_deg", &s.fanAnglesDeg, {0.0, 0.0}, -90.0, 90.0,
                "Fan clipping: min and max angle from the image's y axis, degrees; 0 0 = no fan.");
  schema.option("recon.fan_origin_px", &s.fanOriginPx, {0.0, 0.0}, -100000.0, 100000.0, "Fan apex, pixels.");
  schema.option("recon.fan_radius_start_px", &s.fanRadiusStartPx, 0.0, 0.0, 100000.0, "Fan inner radius, pixels.");
  schema.option("recon.fan_radius_stop_px", &s.fanRadiusStopPx, 500.0, 0.0, 100000.0, "Fan outer radius, pixels.");
  schema.option("recon.pixel_rejection_threshold", &s.pixelRejectionThreshold, -1.0, -1.0, 65535.0,
                "Pixels darker than this are not inserted; -1 = off.");
  schema.option("recon.fill_holes", &s.pixel.fillHoles, false,
                "Fill holes (voxels no pixel reached) with a STICK kernel of length 9; recon.method nearest or "
                "trilinear only (the tent method refuses it and fills between slices with recon.fill_in). PLUS "
                "configs may name other kernels.");
  schema.option("recon.fill_holes_incremental", &s.pixel.fillHolesIncremental, false,
                "Keep holes filled inside each frame's dirty region as frames arrive, instead of one final pass "
                "(needs recon.fill_holes = true).");
}

namespace {
glm::dvec2 toVec2(const std::optional<glm::dvec2>& v, glm::dvec2 def) { return v ? *v : def; }
}  // namespace

ReconSettings fromPlus(const PlusVolumeReconstruction& v) {
  ReconSettings s;
  s.method = v.interpolation == PlusInterpolation::Linear ? Method::Trilinear : Method::Nearest;
  switch (v.compounding) {
    case PlusCompounding::Mean: s.pixel.compounding = Compounding::Mean; break;
    case PlusCompounding::Latest: s.pixel.compounding = Compounding::Latest; break;
    case PlusCompounding::Maximum: s.pixel.compounding = Compounding::Maximum; break;
    case PlusCompounding::ImportanceMask:
      throw InputError("CompoundingMode IMPORTANCE_MASK is not supported by pp5echo");
  }
  s.arithmetic = Arithmetic::Plus;
  s.threads = v.numberOfThreads;
  s.skipInterval = std::max(1, v.skipInterval);
  if (v.clipRectangleOrigin) s.clipOrigin = *v.clipRectangleOrigin;
  if (v.clipRectangleSize) s.clipSize = *v.clipRectangleSize;
  s.fanAnglesDeg = toVec2(v.fanAnglesDeg, {0.0, 0.0});
  s.fanOriginPx = toVec2(v.fanOriginPixel, {0.0, 0.0});
  if (v.fanRadiusStartPixel) s.fanRadiusStartPx = *v.fanRadiusStartPixel;
  if (v.fanRadiusStopPixel) s.fanRadiusStopPx = *v.fanRadiusStopPixel;
  if (v.pixelRejectionThreshold) s.pixelRejectionThreshold = *v.pixelRejectionThreshold;
  s.pixel.fillHoles = v.fillHoles;
  s.pixel.holeFilling = v.holeFilling;
  return s;
}

Reconstructor::Reconstructor(const Grid& g, const ReconSettings& s) : grid_(g), settings_(s) {
  window_ = reach_ = Box3{Index3(0), g.dims};
}

void Reconstructor::setWindow(const Box3& window) {
  window_ = window.intersect(Box3{Index3(0), grid_.dims});
  if (window_.empty()) window_ = Box3{};  // one spelling of "nothing"
  reach_ = reconstructionReach(grid_, settings_, window);
  windowed_ = !(window_ == Box3{Index3(0), grid_.dims});
}

Box3 reconstructionReach(const Grid& g, const ReconSettings& s, const Box3& window) {
  const Box3 all{Index3(0), g.dims};
  const Box3 w = window.intersect(all);
  if (w.empty()) return Box3{};
  return kernelFor(s.method).reach(g, s, w).intersect(all);
}

void checkReconSettings(const ReconSettings& s) {
  kernelFor(s.method).check(s);
  if (s.pixel.fillHolesIncremental && !s.pixel.fillHoles)
    throw InputError("recon.fill_holes_incremental keeps the holes filled as frames arrive; it needs "
                     "recon.fill_holes = true");
}

std::unique_ptr<Reconstructor> makeReconstructor(const Grid& g, const ReconSettings& s,
                                                 std::uint64_t memoryLimitBytes, const std::string& what) {
  // Settings built in code are held to the names a file could give.
  const Kernel& k = kernelFor(checkedEnum(s.method));
  checkedEnum(s.pixel.compounding);
  checkedEnum(s.tent.replacement);
  checkedEnum(s.arithmetic);
  checkReconSettings(s);
  checkGridFits(g, k.bytesPerVoxel(s), what, memoryLimitBytes);
  return k.make(g, s);
}

Grid plusOutputGrid(const std::vector<Mat4>& imageToReference, int width, int height, const ReconSettings& s,
                    const Vec3& spacing) {
  PP5_CHECK(!imageToReference.empty());
  // Corners in pixel-centre coordinates of the clipped frame. PLUS clamps the
  // clip end to clipOrigin + clipSize (no -1), which the baselines confirm.
  double x0 = 0, y0 = 0, x1 = width - 1, y1 = height - 1;
  if (s.clipSize.x > 0 && s.clipSize.y > 0) {
    x0 = std::max(x0, static_cast<double>(s.clipOrigin.x));
    y0 = std::max(y0, static_cast<double>(s.clipOrigin.y));
    x1 = std::min(x1, static_cast<double>(s.clipOrigin.x + s.clipSize.x));
    y1 = std::min(y1, static_cast<double>(s.clipOrigin.y + s.clipSize.y));
  }
  Vec3 lo(std::numeric_limits<double>::infinity()), hi(-std::numeric_limits<double>::infinity());
  for (const Mat4& m : imageToReference)
    for (const Vec3 c : {Vec3(x0, y0, 0), Vec3(x0, y1, 0), Vec3(x1, y0, 0), Vec3(x1, y1, 0)}) {
      const Vec3 p = transformPoint(m, c);
      lo = glm::min(lo, p);
      hi = glm::max(hi, p);
    }
  Grid g;
  g.origin = lo;
  g.spacing = spacing;
  for (int a = 0; a < 3; ++a) {
    const double n = (hi[a] - lo[a]) / spacing[a];
    // No grid that wide fits in memory; and the conversion must be in range.
    if (!(n < 1e7))
      throw InputError(fmt::format("the frames' automatic extent is {} mm along axis {} ({} voxels of {} mm): a "
                                   "pose far from the others? give the extent, or fix the pose",
                                   hi[a] - lo[a], "xyz"[a], n, spacing[a]));
    g.dims[a] = static_cast<std::int64_t>(std::llround(n)) + 1;
  }
  return g;
}

}  // namespace pp5::gp
