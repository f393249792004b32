#pragma once
// A whole simulated acquisition: phantom + probe + B-mode model + sweep. Each
// captured frame is rendered at the probe's true pose and carries what the
// arm or tracker reported (ProbeToTracker), the fixed ReferenceToTracker, the
// true pose (TrueProbeToTracker, for measuring tracking error) and, for arm
// sweeps, the raw A/D counts ("ArmCounts" = "x y theta") and their calibrated
// values ("ArmPosition" = "x_mm y_mm theta_deg").
#include <cstddef>
#include <functional>
#include <memory>
#include <vector>

#include "core/frame.hpp"
#include "core/grid.hpp"
#include "formats/volume_io.hpp"
#include "sim/bmode.hpp"
#include "sim/phantom.hpp"
#include "sim/probe_motion.hpp"
#include "sim/sim_settings.hpp"

namespace pp5::sim {

class SweepSimulator {
public:
  explicit SweepSimulator(const SimSettings& s);
  // The B-mode model refers to the phantom held here, so it stays put.
  SweepSimulator(const SweepSimulator&) = delete;
  SweepSimulator& operator=(const SweepSimulator&) = delete;

  const SimSettings& settings() const { return settings_; }
  const Phantom& phantom() const { return phantom_; }
  const ProbeModel& probe() const { return probe_; }
  const BModeSimulator& bmode() const { return *bmode_; }
  const Sweep& sweep() const { return sweep_; }
  std::size_t frameCount() const { return sweep_.frames.size(); }

  Mat4 imageToProbe() const { return probe_.imageToProbe(); }
  Mat4 referenceToTracker() const { return sweep_.referenceToTracker; }
  // ImageToReference of frame i from the reported pose (what a reconstruction uses).
  Mat4 imageToReference(std::size_t i) const;
  // ImageToReference from the true pose (where the pixels really came from).
  Mat4 trueImageToReference(std::size_t i) const;

  // Frame i, with its pixels, transforms and fields. Thread-safe.
  Frame frame(std::size_t i, BModeDebug* debug = nullptr) const;
  // Renders every frame on `threads` threads (0 = every core) and hands them
  // to `sink` in order; `progress(done, total)` after each. The frames do not
  // depend on the thread count.
  void run(int threads, const std::function<void(Frame&&)>& sink,
           const std::function<void(std::size_t, std::size_t)>& progress = {}) const;

private:
  SimSettings settings_;
  Phantom phantom_;
  ProbeModel probe_;
  std::unique_ptr<BModeSimulator> bmode_;
  Sweep sweep_;
};

// Corners of a width x height image in the Probe frame.
std::vector<Vec3> imageCornersInProbe(const ProbeModel& probe);

// PLUS's automatic extent: the box around every frame's image corners (in
// Reference), grown by `marginMm` on every side, on a grid of `spacing`.
Grid fitGrid(const std::vector<Mat4>& imageToReference, int width, int height, const Vec3& spacing, double marginMm);

// The ground-truth echogenicity on `grid`: at each voxel, the expected pixel
// value (0..255) of the tissue there, BModeSimulator::displayLevel, i.e. the
// log-compressed mean backscatter, with no speckle, PSF, attenuation,
// interfaces or noise. Voxels that a tissue boundary crosses hold the mean
// over 8 sub-samples (partial volume). Throws InputError when the grid does
// not fit in `memoryLimitBytes` (0 = what is available).
Volume truthVolume(const Phantom& phantom, const BModeSimulator& bmode, const Grid& grid, ScalarType type,
                   int threads = 0, std::uint64_t memoryLimitBytes = 0);

// The expected image on `grid`: at each voxel centre, the mean pixel value
// that a frame through it, from a probe oriented as `probeToReference`
// (rigid, Probe -> Reference mm), would show in the "ideal" medium (speckle
// only, no attenuation, interfaces or shadows). That is the backscatter power
// of the tissue on the frame's plane blurred by the in-plane intensity PSF
// (the amplitude PSF squared: Gaussian laterally with the beam width at each
// depth, and along the pulse, with the pixel's height), then log-compressed
// as BModeSimulator::expectedLevel does. There is no blur across the
// elevation: the B-mode model lets the elevation beam shape the speckle, not
// the tissue map. Each voxel holds the point value at its centre, found by
// tracing the tissue boundaries along the depth (closed-form blur) and a
// quadrature over lines an eighth of the lateral sigma apart (at most 32
// per voxel), so it does not depend on the grid's spacing or offset. It is
// what a perfect reconstruction of the frames would converge to, so errors
// against it are the reconstruction's own: speckle left over and blur added.
// The probe's axes must lie along the grid's (within 25 degrees; InputError
// otherwise), since the blur runs along grid lines. Throws InputError when the grid does
// not fit in `memoryLimitBytes` (0 = what is available).
Volume expectedImageVolume(const Phantom& phantom, const BModeSimulator& bmode, const Grid& grid,
                           const Mat4& probeToReference, ScalarType type, int threads = 0,
                           std::uint64_t memoryLimitBytes = 0);

}  // namespace pp5::sim
