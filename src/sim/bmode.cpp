#include "sim/bmode.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

#include "core/error.hpp"
#include "sim/bmode_detail.hpp"
#include "sim/random.hpp"

namespace pp5::sim {

namespace {

// E[20 log10 A] - 20 log10(RMS A) for A the mean envelope of `n` speckle
// samples `dy` apart along a beam with axial PSF sigma `sigma`: the log of
// speckle sits below the log of its RMS (by 2.51 dB, Euler's gamma / 2
// nepers, for one Rayleigh sample; less when correlated samples are
// averaged). The samples' complex correlation is exp(-d^2 / (4 sigma^2)).
// Computed once by a fixed-seed Monte Carlo (to about 0.03 dB) for any n.
double speckleLogBiasDb(int n, double dy, double sigma) {
  std::vector<double> chol(static_cast<std::size_t>(n * n), 0.0);  // lower Cholesky factor
  auto at = [&](int i, int j) -> double& { return chol[static_cast<std::size_t>(i * n + j)]; };
  for (int i = 0; i < n; ++i)
    for (int j = 0; j <= i; ++j) {
      const double d = (i - j) * dy;
      double v = std::exp(-d * d / (4.0 * sigma * sigma));
      for (int k = 0; k < j; ++k) v -= at(i, k) * at(j, k);
      at(i, j) = (i == j) ? std::sqrt(std::max(v, 1e-12)) : v / at(j, j);
    }
  constexpr int kTrials = 40000;
  const std::uint64_t key = mixSeed(0x5eed, 0xb1a5);
  std::vector<double> wr(static_cast<std::size_t>(n)), wi(static_cast<std::size_t>(n));
  double sumDb = 0.0;
  for (int t = 0; t < kTrials; ++t) {
    for (int i = 0; i < n; ++i) {
      wr[static_cast<std::size_t>(i)] = gaussianFromHash(latticeHash(key, t, i, 0)) / std::sqrt(2.0);
      wi[static_cast<std::size_t>(i)] = gaussianFromHash(latticeHash(key, t, i, 1)) / std::sqrt(2.0);
    }
    double mean = 0.0;
    for (int i = 0; i < n; ++i) {
      double zr = 0.0, zi = 0.0;
      for (int k = 0; k <= i; ++k) {
        zr += at(i, k) * wr[static_cast<std::size_t>(k)];
        zi += at(i, k) * wi[static_cast<std::size_t>(k)];
      }
      mean += std::sqrt(zr * zr + zi * zi);
    }
    sumDb += 20.0 * std::log10(mean / n);
  }
  return sumDb / kTrials;
}

double gaussianBeamSigma(double fwhm, double focus, double rayleigh, double depth) {
  const double z = (depth - focus) / rayleigh;
  return fwhm * kFwhmToSigma * std::sqrt(1.0 + z * z);
}

}  // namespace


// ---- probe ------------------------------------------------------------------------

Mat4 ProbeModel::imageToProbe() const {
  const double sx = spacingX(), sy = spacingY();
  return translation(Vec3(-0.5 * (width - 1) * sx, 0.0, 0.0)) * scaling(Vec3(sx, sy, 1.0));
}

double ProbeModel::axialSigmaMm() const {
  // A Gaussian pulse whose two-way spectrum has -6 dB width B has an envelope
  // of time sigma 1 / (2 pi sigma_f), sigma_f = B / 2.355; depth is c t / 2.
  const double sigmaF = fractionalBandwidth * centerMHz * kFwhmToSigma;
  const double sigmaT = 1.0 / (2.0 * std::numbers::pi * sigmaF);
  return 0.5 * kSpeedOfSoundMmPerUs * sigmaT;
}

double ProbeModel::lateralSigmaMm(double depth) const {
  return gaussianBeamSigma(lateralFwhmMm, lateralFocusMm, lateralRayleighMm, depth);
}

double ProbeModel::elevationSigmaMm(double depth) const {
  return gaussianBeamSigma(elevationFwhmMm, elevationFocusMm, elevationRayleighMm, depth);
}

ProbeModel probePreset(const std::string& name) {
  ProbeModel p;
  p.name = name;
  if (name == "paper35") {
    // The 1990 paper's scanner: 3.5 MHz linear array, 98 mm wide, 195 mm deep,
    // frames digitised at 256 x 405. Beam widths typical of such an array
    // with a fixed elevation lens.
    p.width = 256;
    p.height = 405;
    p.widthMm = 98.0;
    p.depthMm = 195.0;
    p.centerMHz = 3.5;
    p.fractionalBandwidth = 0.5;
    p.lateralFwhmMm = 1.8;
    p.lateralFocusMm = 80.0;
    p.lateralRayleighMm = 70.0;
    p.elevationFwhmMm = 4.0;
    p.elevationFocusMm = 70.0;
    p.elevationRayleighMm = 60.0;
    return p;
  }
  if (name == "linear75") {
    // A modern 7.5 MHz linear array: 38 mm wide, 50 mm deep, 256 x 336 pixels.
    p.width = 256;
    p.height = 336;
    p.widthMm = 38.0;
    p.depthMm = 50.0;
    p.centerMHz = 7.5;
    p.fractionalBandwidth = 0.6;
    p.lateralFwhmMm = 0.5;
    p.lateralFocusMm = 20.0;
    p.lateralRayleighMm = 25.0;
    p.elevationFwhmMm = 1.5;
    p.elevationFocusMm = 18.0;
    p.elevationRayleighMm = 15.0;
    return p;
  }
  throw InputError("sim.probe.preset: unknown probe '" + name + "' (expected paper35 or linear75)");
}

ProbeModel makeProbe(const ProbeSettings& s) {
  ProbeModel p = probePreset(std::string(enumName(s.preset)));
  if (s.widthPx > 0) p.width = s.widthPx;
  if (s.heightPx > 0) p.height = s.heightPx;
  if (s.depthMm > 0.0) p.depthMm = s.depthMm;
  return p;
}

// ---- simulator set-up -------------------------------------------------------------

BModeSimulator::BModeSimulator(const Phantom& phantom, const ProbeModel& probe, const BModeSettings& settings,
                               std::uint64_t seed)
    : phantom_(phantom), probe_(probe), settings_(settings), seed_(seed) {
  PP5_CHECK_GT(probe_.width, 1);
  PP5_CHECK_GT(probe_.height, 1);
  const double sx = probe_.spacingX(), sy = probe_.spacingY();
  sigmaAx_ = probe_.axialSigmaMm();
  k2_ = 2.0 * 2.0 * std::numbers::pi * probe_.centerMHz / kSpeedOfSoundMmPerUs;

  // Envelope rows at most 1.5 sigma apart, so a thin echo between two image
  // rows is not lost; the image row is their mean in the log domain.
  osf_ = std::max(1, static_cast<int>(std::ceil(sy / (1.5 * sigmaAx_))));
  subRows_ = probe_.height * osf_;
  subDy_ = sy / osf_;
  firstSubV_ = -0.5 * sy + 0.5 * subDy_;
  vMax_ = firstSubV_ + (subRows_ - 1) * subDy_ + (kPsfCutoff + 0.5) * sigmaAx_;
  fineDy_ = std::min(0.1, 0.5 * sigmaAx_);
  fineRows_ = static_cast<int>(std::ceil(vMax_ / fineDy_)) + 1;

  // Scatterer pitch: `scatterersPerCell` in the PSF's FWHM volume at focus.
  const double cell = probe_.lateralFwhmMm * (sigmaAx_ / kFwhmToSigma) * probe_.elevationFwhmMm;
  pitch_ = std::cbrt(cell / settings_.scatterersPerCell);

  // Lateral kernels per sub-row (unit peak; the beam widens away from focus).
  kernelRadius_.resize(static_cast<std::size_t>(subRows_));
  kernels_.resize(static_cast<std::size_t>(subRows_));
  guard_ = 0;
  for (int r = 0; r < subRows_; ++r) {
    const double sig = probe_.lateralSigmaMm(std::max(0.0, firstSubV_ + r * subDy_)) / sx;
    const int rad = static_cast<int>(std::ceil(kPsfCutoff * sig));
    auto& k = kernels_[static_cast<std::size_t>(r)];
    k.resize(static_cast<std::size_t>(2 * rad + 1));
    for (int d = -rad; d <= rad; ++d) k[static_cast<std::size_t>(d + rad)] = static_cast<float>(std::exp(-0.5 * d * d / (sig * sig)));
    kernelRadius_[static_cast<std::size_t>(r)] = rad;
    guard_ = std::max(guard_, rad);
  }

  // Per fine row: elevation profile, and the normalisations that make the
  // speckle's RMS amplitude equal the tissue's backscatter level and a flat
  // interface's peak equal its reflection coefficient.
  invTwoSigmaE2_.resize(static_cast<std::size_t>(fineRows_));
  halfSlab_.resize(static_cast<std::size_t>(fineRows_));
  speckleNorm_.resize(static_cast<std::size_t>(fineRows_));
  reflectorNorm_.resize(static_cast<std::size_t>(fineRows_));
  maxHalfSlab_ = 0.0;
  const double sqrtPi = std::sqrt(std::numbers::pi);
  for (int f = 0; f < fineRows_; ++f) {
    const double v = (f + 0.5) * fineDy_;
    const double se = probe_.elevationSigmaMm(v);
    const double sl = probe_.lateralSigmaMm(v) / sx;  // in columns
    invTwoSigmaE2_[static_cast<std::size_t>(f)] = static_cast<float>(0.5 / (se * se));
    halfSlab_[static_cast<std::size_t>(f)] = static_cast<float>(kPsfCutoff * se);
    maxHalfSlab_ = std::max(maxHalfSlab_, kPsfCutoff * se);
    // Lateral: scatterers split linearly between two columns, then the
    // Gaussian kernel; the mean over sub-column positions of the summed
    // squared weights, times the column pitch, is the lateral integral.
    const int rad = static_cast<int>(std::ceil(kPsfCutoff * sl)) + 1;
    double kernelSum = 0.0;
    for (int d = -rad; d <= rad; ++d) kernelSum += std::exp(-0.5 * d * d / (sl * sl));
    double lateral = 0.0;
    constexpr int kSub = 32;
    for (int m = 0; m < kSub; ++m) {
      const double fr = (m + 0.5) / kSub;
      for (int d = -rad; d <= rad + 1; ++d) {
        const double w = (1.0 - fr) * std::exp(-0.5 * d * d / (sl * sl)) +
                         fr * std::exp(-0.5 * (d - 1) * (d - 1) / (sl * sl));
        lateral += w * w;
      }
    }
    lateral *= sx / kSub;
    const double power = (sqrtPi * se) * (sqrtPi * sigmaAx_) * lateral / (pitch_ * pitch_ * pitch_);
    speckleNorm_[static_cast<std::size_t>(f)] = static_cast<float>(1.0 / std::sqrt(power));
    reflectorNorm_[static_cast<std::size_t>(f)] = static_cast<float>(1.0 / kernelSum);
  }

  speckleLogBiasDb_ = speckleLogBiasDb(osf_, subDy_, sigmaAx_);
  noiseFloorLevel_ = noiseFloor();

  ideal_ = checkedEnum(settings_.medium) == Medium::Ideal;
  // No attenuation in the ideal medium, so nothing to compensate.
  const double tgc = ideal_                            ? 0.0
                     : settings_.tgcDbPerCmMHz < 0.0 ? phantom_.scan.tgcDbPerCmMHz
                                                       : settings_.tgcDbPerCmMHz;
  tgcDbPerMm_ = 2.0 * tgc * probe_.centerMHz / 10.0;
  echoCutoff_.resize(static_cast<std::size_t>(fineRows_));
  for (int f = 0; f < fineRows_; ++f) {
    const double v = (f + 0.5) * fineDy_;
    echoCutoff_[static_cast<std::size_t>(f)] =
        static_cast<float>(std::pow(10.0, (settings_.noiseDb - kBelowNoiseDb - settings_.gainDb - tgcDb(v)) / 20.0));
  }
  rowGain_.resize(static_cast<std::size_t>(subRows_));
  for (int r = 0; r < subRows_; ++r) {
    const double v = firstSubV_ + r * subDy_;
    rowGain_[static_cast<std::size_t>(r)] = static_cast<float>(std::pow(10.0, (settings_.gainDb + tgcDb(v)) / 20.0));
  }
}

double BModeSimulator::tgcDb(double depth) const {
  const double start = phantom_.scan.tgcStartMm, end = phantom_.scan.tgcEndMm;
  return tgcDbPerMm_ * (std::clamp(depth, start, std::max(start, end)) - start);
}

double BModeSimulator::pixelFromAmplitude(double amplitude) const {
  if (amplitude <= 0.0) return 0.0;
  const double dr = settings_.dynamicRangeDb;
  return std::clamp(255.0 * (20.0 * std::log10(amplitude) + dr) / dr, 0.0, 255.0);
}

double BModeSimulator::backscatterPower(Tissue t) const {
  const double db = tissueProperties(t).backscatterDb;
  return std::isfinite(db) ? std::pow(10.0, db / 10.0) : 0.0;
}

double BModeSimulator::expectedLevel(double power) const {
  // Speckle over any mix of scatterers is a complex Gaussian field, so its
  // envelope is Rayleigh whatever the mix: the log-compressed mean is the log
  // of the RMS amplitude less the speckle bias. The noise adds in power; the
  // floor (a Monte Carlo mean, see noiseFloor) covers what the clamp at
  // black does to faint echoes.
  const double speckle = power * std::pow(10.0, settings_.gainDb / 10.0);
  const double noise = std::pow(10.0, settings_.noiseDb / 10.0);
  const double level = pixelFromAmplitude(std::sqrt(speckle + noise) * std::pow(10.0, speckleLogBiasDb_ / 20.0));
  return std::max(level, noiseFloorLevel_);
}

double BModeSimulator::displayLevel(Tissue t) const {
  const double power = backscatterPower(t);
  return power > 0.0 ? expectedLevel(power) : noiseFloorLevel_;
}

// The expected pixel value where there are no scatterers: electronic noise
// (complex Gaussian, independent per sub-row), its envelope averaged over an
// image row's sub-rows, log-compressed and rounded as formImage does. The
// clamp at black makes it a Monte Carlo mean (fixed seed, about 0.05 level).
double BModeSimulator::noiseFloor() const {
  constexpr int kTrials = 20000;
  const double sigma = std::pow(10.0, settings_.noiseDb / 20.0) / std::sqrt(2.0);
  const std::uint64_t key = mixSeed(0x5eed, 0x401f);
  double sum = 0.0;
  for (int t = 0; t < kTrials; ++t) {
    double mean = 0.0;
    for (int i = 0; i < osf_; ++i) {
      const double re = sigma * gaussianFromHash(latticeHash(key, t, i, 0));
      const double im = sigma * gaussianFromHash(latticeHash(key, t, i, 1));
      mean += std::sqrt(re * re + im * im);
    }
    sum += static_cast<double>(std::lround(pixelFromAmplitude(mean / osf_)));
  }
  return sum / kTrials;
}

}  // namespace pp5::sim
