#pragma once
// Accuracy measures for reconstructions (`pp5echo evaluate`):
//  - against a ground-truth volume (simulated data): RMSE and PSNR over the
//    covered voxels, coverage, and holes inside the swept region;
//  - leave-out (Rohling, Gee & Berman 1999) for real data with no truth: the
//    volume, built without some frames, is sampled at every pixel of those
//    frames through their poses and compared with the pixels.
#include <cstdint>
#include <functional>
#include <optional>
#include <vector>

#include "core/frame.hpp"
#include "core/volume_io.hpp"

namespace pp5::gp {

using CoveredFn = std::function<bool(std::size_t linearIndex)>;

// The swept region: voxels whose centre lies between two consecutive placed
// frames (on opposite sides of, or on, their planes) and inside both frames'
// image rectangles when projected onto them. Poses map pixel (i, j, 0) to mm.
std::vector<std::uint8_t> sweptRegion(const Grid& g, const std::vector<Mat4>& imageToReference, int width,
                                      int height);

struct TruthMetrics {
  std::uint64_t voxels = 0;       // in the grid
  std::uint64_t covered = 0;      // voxels the reconstruction reached
  std::uint64_t swept = 0;        // voxels in the swept region
  std::uint64_t sweptHoles = 0;   // swept voxels not covered
  double rmse = 0.0;              // over covered voxels, grey levels
  double mae = 0.0;
  double psnrDb = 0.0;            // 20 log10(255 / rmse)
  double coverage() const { return voxels ? static_cast<double>(covered) / static_cast<double>(voxels) : 0.0; }
  double holeFraction() const { return swept ? static_cast<double>(sweptHoles) / static_cast<double>(swept) : 0.0; }
};

// `recon` and `truth` must share the grid (InputError otherwise). With a
// non-empty `swept` mask, RMSE is measured over covered voxels inside it.
TruthMetrics compareWithTruth(const Volume& recon, const CoveredFn& covered, const Volume& truth,
                              const std::vector<std::uint8_t>& swept);

// Trilinear sample at a world point; nullopt when any of the 8 neighbours is
// outside the grid or not covered.
std::optional<double> sampleCovered(const Volume& v, const CoveredFn& covered, const Vec3& world);

struct LeaveOutMetrics {
  std::uint64_t framesHeldOut = 0;
  std::uint64_t pixelsCompared = 0;
  std::uint64_t pixelsSkipped = 0;  // uncovered or outside the grid
  double mae = 0.0;
  double rmse = 0.0;
  void add(double diff) {
    sumAbs_ += std::abs(diff);
    sumSq_ += diff * diff;
    ++pixelsCompared;
  }
  void finish();

private:
  double sumAbs_ = 0.0, sumSq_ = 0.0;
};

// Compares every pixel of a held-out frame with the volume sampled at its position.
void compareHeldOutFrame(const Volume& v, const CoveredFn& covered, const Frame& f, const Mat4& imageToReference,
                         LeaveOutMetrics& m);

}  // namespace pp5::gp
