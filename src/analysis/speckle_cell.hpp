#pragma once
// The probe's in-plane resolution cell, measured from the frames themselves
// (`pp5echo evaluate speckle`; issue 18's "kernels from the data").
//
// One frame's autocorrelation measures its anatomy as much as its speckle:
// its width grows with the window it is taken over. Two consecutive frames of
// a sweep show nearly the same anatomy but speckle that has partly or wholly
// decorrelated, so their difference keeps the speckle and cancels the
// anatomy. The speckle's in-plane correlation is the beam's (for a Gaussian
// beam of two-way amplitude FWHM w, the speckle's intensity autocorrelation
// has a half width at half maximum of about w / 2), so the half width at half
// maximum of the difference's autocorrelation, along the image's rows
// (lateral) and its columns (axial), is the cell. Along the sweep, three
// consecutive frames tell how fast the speckle decorrelates (addTriple).
//
// Only pixels inside the clip rectangle and fan that are non-zero in both
// frames take part, in blocks of 32 x 32 pixels whose difference is
// correlated between horizontal neighbours: a water bath or a shadow holds
// electronic noise, white, which time-gain compensation can make as bright
// as tissue, and which would read as a cell of under a pixel
// (docs/quality.md, "What the leave-out protocol rewards").
#include <cstdint>
#include <optional>
#include <vector>

#include "core/frame.hpp"
#include "reconstruction/fan_mask.hpp"

namespace pp5::gp {

struct SpeckleCell {
  // Half width at half maximum of the autocorrelation, pixels; nullopt when it
  // stays above one half up to the largest lag measured.
  std::optional<double> lateralPx, axialPx;
  // The normalised autocorrelation at lags 0, 1, ... (1 at lag 0).
  std::vector<double> lateral, axial;
  std::uint64_t pairs = 0;   // frame pairs measured
  std::uint64_t pixels = 0;  // difference pixels taken, over every pair

  // Along the sweep (addTriple): the half width at half maximum of the
  // speckle's correlation between frames, mm; nullopt when no triple was
  // measured, or when the frames are too far apart (the speckle of the nearer
  // pair already decorrelated) or too close for it to be read.
  std::optional<double> elevationMm;
  // Why elevationMm is what it is.
  enum class Elevation {
    Measured,
    NoTriple,      // no triple of consecutive frames with speckle
    Decorrelated,  // the variance ratio is near 1: the frames are farther apart than the speckle stays correlated
    Correlated,    // near its top: the frames are too close for the speckle to decorrelate
  };
  Elevation elevation = Elevation::NoTriple;
  std::uint64_t triples = 0;
  double nearMm = 0.0, farMm = 0.0;  // mean spacing of a triple's first frame to its second, and to its third
  double varianceRatio = 0.0;        // var(first - third) / var(first - second), pooled
};

class SpeckleCellMeter {
 public:
  // maxLagPx: the largest lag measured, pixels (1 or more).
  explicit SpeckleCellMeter(int maxLagPx = 64);

  // Adds the difference of two frames of the same size (a pair of another
  // size than the first pair's is an InputError). `runs` are the clip
  // rectangle and fan (pixelRuns). Returns whether any pixel took part.
  bool add(const Frame& previous, const Frame& current, const std::vector<PixelRun>& runs);

  // Adds three consecutive frames for the cell along the sweep, with the
  // spacing (mm) of the first to the second and of the first to the third.
  // The speckle's correlation between frames x apart falls as
  // exp(-x^2 / (2 s^2)), so var(a - c) / var(a - b) = (1 - rho(ac)) / (1 - rho(ab))
  // gives s with no need for the speckle's own variance. Over the blocks where
  // a - b is speckle. Returns whether any pixel took part.
  bool addTriple(const Frame& a, const Frame& b, const Frame& c, double abMm, double acMm,
                 const std::vector<PixelRun>& runs);

  // The cell from every pair and triple added so far.
  SpeckleCell result() const;

 private:
  int maxLag_;
  int width_ = -1, height_ = -1;
  std::uint64_t pairs_ = 0, pixels_ = 0;
  // Sums of products and their counts per lag, along rows and along columns.
  std::vector<double> sumX_, sumY_;
  std::vector<std::uint64_t> countX_, countY_;
  // Triples: the sums of the two variances and of the spacings.
  std::uint64_t triples_ = 0;
  double nearVar_ = 0.0, farVar_ = 0.0, nearMm_ = 0.0, farMm_ = 0.0;
  void checkSize(const Frame& f);
};

// A tent kernel scaled from the measured cell as the default kernel (2, 1, 3 mm)
// is from the simulated paper35 probe's frames, 2 mm apart: half-widths of
// twice the lateral cell, twice the axial cell or the pixel where that is
// larger (an axial cell under a pixel is the pixel's), and 1.5 times the
// median spacing of consecutive frames. Chosen on that sweep alone; checked
// on others in docs/quality.md. `evaluate speckle` prints it as a suggestion;
// recon.kernel_from_frames (off by default) uses it.
struct KernelHalfWidths {
  double lateralMm = 0.0, axialMm = 0.0, elevationMm = 0.0;
};
inline constexpr double kKernelPerLateralCell = 2.0;
inline constexpr double kKernelPerAxialCell = 2.0;
inline constexpr double kKernelPerFrameSpacing = 1.5;
// nullopt when either half width was not measured. `floorXMm`/`floorYMm`: the
// pixel the reconstruction is given where that is coarser than the measured
// frames' (a run that subsamples them); a cell under it counts as it.
std::optional<KernelHalfWidths> kernelFromCell(const SpeckleCell& cell, double pixelXMm, double pixelYMm,
                                               double frameSpacingMm, double floorXMm = 0.0, double floorYMm = 0.0);

// Where a normalised autocorrelation (1 at lag 0) first falls below one half,
// interpolated linearly between the lags around it; nullopt if it never does.
std::optional<double> halfWidthAtHalfMaximum(const std::vector<double>& r);

}  // namespace pp5::gp
