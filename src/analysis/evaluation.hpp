#pragma once
// Accuracy measures for reconstructions (`pp5echo evaluate`):
//  - against a ground-truth volume (simulated data): RMSE and PSNR over the
//    swept region's voxels that hold a reconstructed value (directly covered
//    or hole-filled), the same over its tissue, coverage, and the holes left
//    inside the swept region;
//  - leave-out (Rohling, Gee & Berman 1999) for real data with no truth: the
//    volume, built without some frames, is sampled at every pixel of those
//    frames through their poses and compared with the pixels.
#include <cstdint>
#include <functional>
#include <optional>
#include <vector>

#include "core/frame.hpp"
#include "formats/volume_io.hpp"
#include "reconstruction/fan_mask.hpp"

namespace pp5::gp {

using CoveredFn = std::function<bool(std::size_t linearIndex)>;

// The swept region: voxels whose centre lies between two consecutive placed
// frames (on opposite sides of, or on, their planes) and inside both frames'
// image rectangles when projected onto them. Poses map pixel (i, j, 0) to mm.
std::vector<std::uint8_t> sweptRegion(const Grid& g, const std::vector<Mat4>& imageToReference, int width,
                                      int height);

// How far from tissue the background counts as its edge (TruthMetrics).
inline constexpr double kEdgeMm = 4.0;

struct TruthMetrics {
  std::uint64_t voxels = 0;       // in the grid
  std::uint64_t covered = 0;      // voxels that hold a value
  std::uint64_t swept = 0;        // voxels in the swept region
  std::uint64_t sweptHoles = 0;   // swept voxels with no value
  std::uint64_t compared = 0;     // voxels the errors are over
  std::uint64_t tissueCompared = 0;  // ... of which tissue
  double rmse = 0.0;              // grey levels
  double mae = 0.0;
  double psnrDb = 0.0;            // 20 log10(255 / rmse)
  // Over the compared voxels whose truth is brighter than the truth's darkest
  // level (the background, e.g. water at the noise floor) by more than one
  // grey level: the tissue and its boundaries, where the methods differ most.
  double rmseTissue = 0.0;
  double maeTissue = 0.0;
  // Mean signed error (recon - truth): a method that brightens or darkens
  // shows here, where RMSE mixes it with noise and blur.
  double bias = 0.0;
  double biasTissue = 0.0;
  // The background (not tissue) split by distance: within `edgeMm` of a
  // tissue voxel along every axis (a box around it), where a kernel that
  // spreads the tissue's echo into its neighbours pays, and the rest, where
  // averaging the noise floor pays. tissue + edge + far = compared.
  double edgeMm = 0.0;
  std::uint64_t edgeCompared = 0;
  std::uint64_t farCompared = 0;
  double rmseEdge = 0.0;
  double biasEdge = 0.0;
  double rmseFar = 0.0;
  double coverage() const { return voxels ? static_cast<double>(covered) / static_cast<double>(voxels) : 0.0; }
  double holeFraction() const { return swept ? static_cast<double>(sweptHoles) / static_cast<double>(swept) : 0.0; }
};

// `recon` and `truth` must share the grid (InputError otherwise). `covered`
// says where `recon` holds a value. With a non-empty `swept` mask the errors
// are measured over the voxels with a value inside it, else over all with one.
TruthMetrics compareWithTruth(const Volume& recon, const CoveredFn& covered, const Volume& truth,
                              const std::vector<std::uint8_t>& swept, double edgeMm = kEdgeMm);

// Trilinear sample at a world point; nullopt when any of the 8 neighbours is
// outside the grid or not covered.
std::optional<double> sampleCovered(const Volume& v, const CoveredFn& covered, const Vec3& world);

struct LeaveOutMetrics {
  std::uint64_t framesHeldOut = 0;
  std::uint64_t pixelsCompared = 0;
  std::uint64_t pixelsSkipped = 0;  // uncovered or outside the grid
  double mae = 0.0;
  double rmse = 0.0;
  double bias = 0.0;  // mean of (volume - held-out pixel)
  void add(double diff) {
    sum_ += diff;
    sumAbs_ += std::abs(diff);
    sumSq_ += diff * diff;
    ++pixelsCompared;
  }
  void finish();

private:
  double sum_ = 0.0, sumAbs_ = 0.0, sumSq_ = 0.0;
};

// How a held-out pixel is read from the volume.
enum class LeaveOutReading {
  // The trilinear value where all 8 neighbours hold a value (pp5echo's).
  Trilinear,
  // As PLUS's volume is read through a trilinear reslice into its own type:
  // the trilinear value rounded to the nearest grey level, and a pixel whose
  // rounded value is 0 not compared ("value != 0 as coverage"); all 8
  // neighbours must still hold a value. It gives PLUS's leave-out errors
  // (docs/quality.md).
  PlusGreyLevels,
};

// Compares every pixel of a held-out frame inside `runs` (the clip rectangle
// and fan the reconstruction used, fan_mask.hpp) with the volume sampled at
// its position; pixels outside them are neither compared nor counted.
void compareHeldOutFrame(const Volume& v, const CoveredFn& covered, const Frame& f, const Mat4& imageToReference,
                         const std::vector<PixelRun>& runs, LeaveOutMetrics& m,
                         LeaveOutReading reading = LeaveOutReading::Trilinear);

}  // namespace pp5::gp
