#pragma once
// B-mode image formation by convolution.
//
// Scatterers sit on a jittered world lattice with Gaussian amplitudes drawn
// from a hash of (seed, lattice index), so they are fixed in space: nearby
// slices see the same scatterers and their speckle is correlated, and it
// decorrelates only over the elevation beam width. Each scatterer's strength
// is its tissue's backscatter. The image of a frame is the complex baseband
// sum over scatterers of amplitude * PSF * exp(-i 2k v_s): the PSF is
// Gaussian laterally and in elevation, with widths that follow a focused
// Gaussian beam. Axially the pulse is a Gaussian-modulated sinusoid at the
// centre frequency: the RF line would be sum a_s G(v - v_s) cos(2k (v - v_s)),
// whose analytic signal (what quadrature demodulation recovers) is
// exp(i 2k v) times the baseband sum above, so the envelope is its magnitude
// and the RF never needs sampling at the carrier.
//
// Each beam line is traced through the phantom: interfaces echo specularly
// (impedance jump, times a falloff with the angle between beam and surface
// normal), a rough surface (bone) also scatters from a thin layer under it,
// and the two-way transmission (attenuation per tissue and frequency,
// interface losses) darkens everything below, which makes acoustic shadows.
// An interface's echoes see the energy that arrives at it: its own
// transmission loss only darkens what lies beyond.
// Then time-gain compensation, electronic noise and log compression to 8 bits.
//
// Everything is a deterministic function of (seed, frame index, pose): the
// frame index only seeds the electronic noise.
#include <cstdint>
#include <string>
#include <vector>

#include "core/frame.hpp"
#include "core/transform.hpp"
#include "sim/phantom.hpp"
#include "sim/sim_settings.hpp"

namespace pp5::sim {

constexpr double kSpeedOfSoundMmPerUs = 1.54;

// A linear-array probe. The image's pixel (i, j) lies at lateral
// (i - (width-1)/2) * spacingX() and depth j * spacingY() in the Probe frame,
// whose origin is the centre of the transducer face: x lateral, y axial (away
// from the face), z elevation.
struct ProbeModel {
  std::string name;
  int width = 256, height = 405;  // pixels
  double widthMm = 98.0, depthMm = 195.0;
  double centerMHz = 3.5;
  double fractionalBandwidth = 0.5;  // -6 dB width of the two-way spectrum / centre frequency
  // Two-way amplitude beam profiles: FWHM at the focus, focal depth, and the
  // depth over which the width grows by sqrt(2) (Rayleigh range).
  double lateralFwhmMm = 1.8, lateralFocusMm = 80.0, lateralRayleighMm = 70.0;
  double elevationFwhmMm = 4.0, elevationFocusMm = 70.0, elevationRayleighMm = 60.0;

  double spacingX() const { return widthMm / width; }
  double spacingY() const { return depthMm / height; }
  // Pixel (i, j, 0) -> Probe mm; includes the mm-per-pixel scale (elevation scale 1).
  Mat4 imageToProbe() const;
  double axialSigmaMm() const;  // pulse envelope (Gaussian sigma in depth)
  double lateralSigmaMm(double depthMm) const;
  double elevationSigmaMm(double depthMm) const;
};

// "paper35" | "linear75"; throws InputError otherwise.
ProbeModel probePreset(const std::string& name);
// The preset with the settings' size overrides applied.
ProbeModel makeProbe(const ProbeSettings& s);

// Intermediate results of one render, for tests and diagnostics.
struct BModeDebug {
  int width = 0;
  int subRows = 0;     // rows of the envelope (height * oversample)
  int oversample = 1;  // envelope rows per image row
  // Envelope after TGC and noise, before log compression, at sub-row
  // resolution (row-major, subRows x width); 1.0 is white at 0 dB.
  std::vector<float> envelope;
  std::size_t scatterers = 0;  // scatterers that contributed
};

class BModeSimulator {
public:
  // Keeps a reference to `phantom`, which must outlive the simulator.
  BModeSimulator(const Phantom& phantom, const ProbeModel& probe, const BModeSettings& settings, std::uint64_t seed);

  // The image seen by a probe at `probeToReference` (rigid). Allocates `out`
  // as width x height U8. Thread-safe.
  void render(const Mat4& probeToReference, std::uint64_t frameIndex, Frame& out, BModeDebug* debug = nullptr) const;

  // Expected pixel value of the tissue's fully developed speckle with no
  // attenuation left uncompensated: the log-compression mapping applied to
  // the tissue's mean backscatter amplitude in the log domain (the RMS
  // amplitude less the mean-of-log bias of speckle, 2.51 dB for one Rayleigh
  // sample, a little less after the sub-row averaging), with the electronic
  // noise added in power; a medium with no scatterers (water) shows the noise
  // floor. This is what the ground-truth volume holds and what an ideal
  // reconstruction would show (exactly so with the "ideal" medium).
  double displayLevel(Tissue t) const;
  // Log compression: amplitude (1.0 = white at 0 dB gain) -> pixel value, clamped to 0..255.
  double pixelFromAmplitude(double amplitude) const;
  // Mean backscatter power (RMS amplitude squared, 1 = white at 0 dB gain) of
  // a tissue; 0 for a medium without scatterers.
  double backscatterPower(Tissue t) const;
  // Expected pixel value where the mean echo power (before gain) is `power`:
  // the same mapping as displayLevel, for any mix of tissues (the expected
  // image, sim/simulate.hpp).
  double expectedLevel(double power) const;
  // displayLevel of a medium with no scatterers: the electronic noise floor.
  double noiseFloorLevel() const { return noiseFloorLevel_; }

  const ProbeModel& probe() const { return probe_; }
  const Phantom& phantom() const { return phantom_; }
  double latticePitchMm() const { return pitch_; }
  int oversample() const { return osf_; }

private:
  struct Workspace;
  double noiseFloor() const;
  struct FrameGeometry;
  void traceColumns(const FrameGeometry& g, const std::vector<int>& bodies, Workspace& ws) const;
  void addWires(const FrameGeometry& g, Workspace& ws) const;
  std::size_t addScatterers(const FrameGeometry& g, Workspace& ws) const;
  void formImage(std::uint64_t frameIndex, Workspace& ws, Frame& out, BModeDebug* debug) const;
  // Time-gain compensation at a depth, dB.
  double tgcDb(double depth) const;
  // Adds a point echo at (lateral column position cu, depth v) to the complex buffer.
  void splat(Workspace& ws, double cu, double v, float re, float im) const;

  const Phantom& phantom_;
  ProbeModel probe_;
  BModeSettings settings_;
  bool ideal_ = false;  // medium "ideal"

  std::uint64_t seed_;

  // Derived, fixed per probe.
  int osf_ = 1;              // sub-rows per image row
  int subRows_ = 0;
  double subDy_ = 0.0;       // sub-row pitch, mm
  double firstSubV_ = 0.0;   // depth of sub-row 0
  double vMax_ = 0.0;        // deepest depth traced
  double fineDy_ = 0.0;      // pitch of the per-column depth tables
  int fineRows_ = 0;
  double sigmaAx_ = 0.0;
  double k2_ = 0.0;          // round-trip wavenumber 2 * 2 pi f / c, rad/mm
  double pitch_ = 0.0;       // scatterer lattice pitch
  double maxHalfSlab_ = 0.0; // largest elevation half-width considered
  double tgcDbPerMm_ = 0.0;
  double speckleLogBiasDb_ = 0.0;  // mean log of speckle relative to its RMS
  double noiseFloorLevel_ = 0.0;   // expected pixel value of noise alone
  int guard_ = 0;            // extra columns each side for the lateral PSF
  std::vector<float> invTwoSigmaE2_;  // per fine row: 1 / (2 sigma_e^2)
  std::vector<float> halfSlab_;       // per fine row: 3 sigma_e
  std::vector<float> speckleNorm_;    // per fine row
  std::vector<float> reflectorNorm_;  // per fine row: 1 / sum of the lateral kernel
  std::vector<int> kernelRadius_;     // per sub-row
  std::vector<std::vector<float>> kernels_;  // per sub-row, 2r+1 taps
  std::vector<float> echoCutoff_;     // per fine row: weakest scatterer strength worth simulating
  std::vector<float> rowGain_;        // per sub-row: TGC and gain
};

}  // namespace pp5::sim
