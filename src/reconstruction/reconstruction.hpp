#pragma once
// Incremental reconstruction: each tracked frame is inserted into a regular
// grid the moment it arrives, and the voxels it changed are returned as a
// DirtyRegion. Pure library code (no MPI), shared by the serial pipeline, the
// GP rank and `pp5echo reconstruct`.
//
// Methods:
//  - tent:       Ohbuchi & Fuchs 1990. Forward mapping with an asymmetric
//                triangular kernel that rotates with the slice, 3D weight
//                buffer, adaptive inter-slice fill-in, replacement of aging data.
//  - nearest / trilinear: PLUS-compatible pixel nearest neighbour and
//                trilinear splatting, with MEAN / LATEST / MAXIMUM compounding,
//                clip rectangle, fan clipping and pixel rejection.
// Every method gives the same answer for any thread count, and inserting N
// frames one at a time equals inserting them in one batch, bitwise.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/frame.hpp"
#include "core/grid.hpp"
#include "formats/plus_config.hpp"
#include "formats/volume_io.hpp"
#include "reconstruction/dirty_region.hpp"
#include "core/enum_names.hpp"

namespace pp5 {
class ConfigSchema;
}

namespace pp5::gp {

enum class Method { Tent, Nearest, Trilinear };
enum class Compounding { Mean, Latest, Maximum };
enum class Replacement { Accumulate, MotionVector, Decay };
// plus: PLUS's own arithmetic (14-bit fixed point, 8-bit running mean that
// truncates, 16-bit accumulator), for reproducing its results bit for bit.
// float: exact weighted means in float accumulators, rounded once on output.
enum class Arithmetic { Float, Plus };

// [recon] settings. Defaults are the paper's method for the simulated probe.
// The tent method's own settings (recon.method = "tent").
struct TentSettings {
  // Half-widths along the slice's own axes, mm.
  double kernelLateralMm = 2.0;
  double kernelAxialMm = 1.0;
  double kernelElevationMm = 3.0;
  // Derive the half-widths the user did not set from the frames (batch
  // commands only; analysis/speckle_run.hpp).
  bool kernelFromFrames = false;

  // Inter-slice fill-in.
  bool fillIn = true;
  double fillInMaxGapMm = 12.0;         // no fill-in across a larger jump
  double fillInMaxAngleDeg = 20.0;      // ... or a larger rotation

  // Replacement of aging data.
  Replacement replacement = Replacement::Accumulate;
  double motionVectorNewWeight = 0.8;      // share of the new sweep in the replaced value
  int motionVectorBrick = 8;               // voxels per side of a motion-vector cell
  double decayTauS = 5.0;                  // time constant of the decay, seconds
};

// The settings of PLUS's methods (recon.method = "nearest" or "trilinear").
struct PixelSettings {
  Compounding compounding = Compounding::Mean;
  // Hole filling.
  bool fillHoles = false;
  bool fillHolesIncremental = false;       // keep holes filled inside each dirty region
  std::vector<PlusHoleFillingElement> holeFilling;
};

// [recon]: what every method shares, and each method's own settings (the TOML
// keys stay flat: recon.kernel_lateral_mm, recon.compounding, ...).
struct ReconSettings {
  Method method = Method::Tent;
  Arithmetic arithmetic = Arithmetic::Float;
  int threads = 0;                      // 0 = every core; the result does not depend on it
  int skipInterval = 1;                 // insert every n-th frame

  // PLUS-style pixel selection (all methods).
  glm::ivec2 clipOrigin{0, 0};
  glm::ivec2 clipSize{0, 0};               // 0 0 = whole frame
  glm::dvec2 fanAnglesDeg{0.0, 0.0};       // 0 0 = no fan
  glm::dvec2 fanOriginPx{0.0, 0.0};
  double fanRadiusStartPx = 0.0;
  double fanRadiusStopPx = 500.0;
  double pixelRejectionThreshold = -1.0;   // < 0 = off

  TentSettings tent;
  PixelSettings pixel;
};

void registerOptions(ConfigSchema& schema, ReconSettings& s);
// The settings a PLUS VolumeReconstruction element asks for (plus arithmetic).
ReconSettings fromPlus(const PlusVolumeReconstruction& v);

struct InsertResult {
  DirtyRegion dirty;               // every voxel whose output value may have changed
  // From a reconstructor whose reportsChangedRuns() is true: row runs that
  // hold every voxel whose output bits changed (runs may overlap and hold
  // voxels that kept their bits). Empty otherwise.
  std::vector<RowRun> changedRuns;
  std::uint64_t pixelsInserted = 0;
  int fillInSlices = 0;            // intermediate slices splatted before this frame
};

class Reconstructor {
public:
  virtual ~Reconstructor() = default;
  const Grid& grid() const { return grid_; }
  const ReconSettings& settings() const { return settings_; }

  // Inserts one frame (pixels in MF orientation) at `imageToReference` (mm,
  // including pixel spacing). `timeS` drives the decay replacement. The output
  // volume is up to date inside the returned dirty region on return.
  virtual InsertResult insert(const Frame& f, const Mat4& imageToReference, double timeS) = 0;
  // Whether insert() lists the voxels whose output bits it changed
  // (InsertResult::changedRuns), so that later stages need not compare the
  // dirty region's values with a copy (rendering/change_tracker.hpp).
  virtual bool reportsChangedRuns() const { return false; }
  // Final passes that are not incremental (e.g. hole filling when
  // fill_holes_incremental = false). Idempotent.
  virtual void finish() {}

  // ---- Windowed reconstruction (the `slab` partitioning: a GP keeps only its brick and ghosts exact) ----
  //
  // Restricts the work to `window` (voxels, clipped to the grid); call before the first frame (InvariantError
  // otherwise). Afterwards output() and weights() equal an unrestricted reconstructor's, bitwise, at every voxel
  // of the window, for any sequence of insert/advance/restorePrevious calls that obeys the rules below; voxels
  // outside it may hold anything. The dirty region returned by insert covers every voxel of the window whose
  // output changed (it may reach outside).
  //
  // The rule: a frame must go to insert() when its splat, or the fill-in between it and the previous frame,
  // reaches a voxel of reach() (the window as the method needs it, see reconstructionReach) with a nonzero
  // weight; any other frame may go to advance(). The host's test is geometric and conservative: the support
  // slabs of the frame and of the fill-in slices (the pixel rectangle grown by the kernel's half-widths, the
  // tent's dirty region) against the box reach(). (Diffing output() and weights() of a reference run is not
  // quite enough: a weight lost to float rounding, or a motion-vector rebase, changes the state invisibly.)
  //
  // tent: splats only the voxels of reach(), with the same per-voxel arithmetic, so those get the same bits;
  // each voxel's state depends only on its own history, the slice and, with motion vectors, its cell (which
  // is why the reach is rounded out to whole cells). The dirty region keeps the bricks that overlap window().
  // nearest / trilinear: ignore the window and splat every frame given to insert() in full (that is exact, and
  // the dirty region is the unrestricted one); they keep no state from one frame to the next, so advance() only
  // checks its inputs and returns an empty result, and restorePrevious() only checks that it may be called.
  virtual void setWindow(const Box3& window);
  // The frame's pose and time only, for a frame whose splat (and the fill-in before it) cannot reach the window:
  // every piece of state advances exactly as insert() would advance it (time origin, previous pose and time,
  // the jump test, the motion direction and its anchor), nothing is splatted, the dirty region is empty.
  // The previous frame's pixels are then unknown: the next insert() splats no fill-in slices unless
  // restorePrevious() gave them. The inputs are checked as insert() checks them, with the same InputError
  // messages (the frame named by its time, as it has no index here); a refused frame changes nothing.
  virtual InsertResult advance(int width, int height, const Mat4& imageToReference, double timeS) = 0;
  // The pixels of the frame last passed to advance(), given afterwards because the fill-in between it and the
  // next frame can reach the window: the next insert() then fills in exactly as an unrestricted reconstructor
  // would. Call it right after that advance(), at most once: InvariantError if the last call was not an
  // advance() or if `f` has another size than the advanced frame; InputError for a pixel buffer of the wrong
  // size.
  virtual void restorePrevious(const Frame& f) = 0;
  // The window given to setWindow, clipped to the grid (the whole grid without one; empty if it missed the grid).
  const Box3& window() const { return window_; }
  // reconstructionReach(grid(), settings(), window): the voxels a frame must reach to need insert().
  const Box3& reach() const { return reach_; }

  // Reconstructed values in grey levels (F32), 0 where nothing was inserted.
  virtual const Volume& output() const = 0;
  // Accumulated weight per voxel (F32; 0 = not covered).
  virtual Volume weights() const = 0;
  virtual bool covered(std::size_t linearIndex) const = 0;
  // Whether output() holds a reconstructed value there: covered, or a hole
  // that hole filling filled (a hole no kernel could fill is 0 and has none).
  virtual bool hasValue(std::size_t linearIndex) const { return covered(linearIndex); }

protected:
  Reconstructor(const Grid& g, const ReconSettings& s);
  // Whether setWindow asked for less than the whole grid.
  bool windowed() const { return windowed_; }
  Grid grid_;
  ReconSettings settings_;

private:
  Box3 window_, reach_;
  bool windowed_ = false;
};

// The voxels a windowed reconstructor must see every change of to keep `window` exact: `window` clipped to
// the grid, rounded out to whole motion-vector cells (recon.motion_vector_brick voxels, aligned to the grid)
// for the tent method with motion vectors, as a cell's direction and rebasing depend on every voxel in it;
// grown by the hole-filling reach for the pixel methods with hole filling, as a hole's value depends on the
// voxels around it. A host deciding which GPs need a frame's pixels tests the frame's support against this box.
Box3 reconstructionReach(const Grid& g, const ReconSettings& s, const Box3& window);

// InputError for settings no reconstructor can honour: hole filling
// (recon.fill_holes, fill_holes_incremental, PLUS HoleFilling elements) with
// the tent method, which keeps no per-voxel weights to fill from.
void checkReconSettings(const ReconSettings& s);

// Refuses grids that do not fit in memory (InputError naming `what`) before
// allocating, and what checkReconSettings refuses.
std::unique_ptr<Reconstructor> makeReconstructor(const Grid& g, const ReconSettings& s,
                                                 std::uint64_t memoryLimitBytes = 0,
                                                 const std::string& what = "reconstruction grid");

// PLUS's automatic output extent: the box around the clipped corners (pixel
// centres) of every frame, origin at its minimum, round(size/spacing)+1 voxels.
Grid plusOutputGrid(const std::vector<Mat4>& imageToReference, int width, int height, const ReconSettings& s,
                    const Vec3& spacing);

}  // namespace pp5::gp

namespace pp5 {

template <>
struct EnumNames<gp::Method> {
  static constexpr std::string_view key = "recon.method";
  static constexpr std::array<std::pair<gp::Method, std::string_view>, 3> names{{
      {gp::Method::Tent, "tent"},
      {gp::Method::Nearest, "nearest"},
      {gp::Method::Trilinear, "trilinear"}}};
};

template <>
struct EnumNames<gp::Compounding> {
  static constexpr std::string_view key = "recon.compounding";
  static constexpr std::array<std::pair<gp::Compounding, std::string_view>, 3> names{{
      {gp::Compounding::Mean, "mean"},
      {gp::Compounding::Latest, "latest"},
      {gp::Compounding::Maximum, "maximum"}}};
};

template <>
struct EnumNames<gp::Replacement> {
  static constexpr std::string_view key = "recon.replacement";
  static constexpr std::array<std::pair<gp::Replacement, std::string_view>, 3> names{{
      {gp::Replacement::Accumulate, "accumulate"},
      {gp::Replacement::MotionVector, "motion_vector"},
      {gp::Replacement::Decay, "decay"}}};
};

template <>
struct EnumNames<gp::Arithmetic> {
  static constexpr std::string_view key = "recon.arithmetic";
  static constexpr std::array<std::pair<gp::Arithmetic, std::string_view>, 2> names{{
      {gp::Arithmetic::Float, "float"},
      {gp::Arithmetic::Plus, "plus"}}};
};

}  // namespace pp5
