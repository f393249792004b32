#pragma once
// Scan coverage, for the person holding the probe: which parts of the grid
// the frames have swept, where the newest frame lies on screen, and whether
// consecutive frames are farther apart than the reconstruction can fill
// (holes: the probe moves too fast).
#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include "core/camera.hpp"
#include "core/grid.hpp"
#include "core/transform.hpp"
#include "reconstruction/reconstruction.hpp"

namespace pp5::host {

class Coverage {
public:
  // Cells of `cellMm` (at least one voxel) over the grid. The gap limit is
  // what `recon` fills between consecutive frames: with fill-in, its largest
  // corner displacement; without, the kernel's elevation reach on both sides.
  Coverage(const Grid& grid, const gp::ReconSettings& recon, double cellMm = 4.0);

  // A frame of width x height pixels at `imageToReference`: marks the cells
  // its plane passes through and measures its gap to the previous frame.
  void add(const Mat4& imageToReference, int width, int height);

  // Share of the grid's cells swept so far, 0..1.
  double fraction() const;
  bool covered(const Vec3& worldMm) const;
  // The largest displacement of an image corner from the previous frame (mm), and the limit.
  double lastGapMm() const { return gapMm_; }
  double gapLimitMm() const { return limitMm_; }
  bool gapWarning() const { return gapMm_ > limitMm_; }
  std::uint64_t frames() const { return frames_; }

private:
  Grid grid_;
  double cellMm_, limitMm_;
  std::array<std::int64_t, 3> cells_{};
  std::vector<std::uint8_t> hit_;
  std::uint64_t hits_ = 0, frames_ = 0;
  double gapMm_ = 0.0;
  std::optional<std::array<Vec3, 4>> prevCorners_;
};

// The four corners of a frame in world mm (pixel corners (0,0), (w,0), (w,h), (0,h)).
std::array<Vec3, 4> frameCorners(const Mat4& imageToReference, int width, int height);

// The corners projected into `camera`'s image (pixels), or nullopt when one
// lies behind the eye.
std::optional<std::array<std::array<double, 2>, 4>> outlineOnScreen(const Camera& camera,
                                                                     const std::array<Vec3, 4>& corners);

}  // namespace pp5::host
