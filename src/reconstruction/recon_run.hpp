#pragma once
// A PLUS sequence through a reconstructor (what `reconstruct`, `evaluate` and a
// run of a sequence share): poses from a PLUS config, frames that cannot be
// placed skipped and counted, progress shown on long input; and the grid they
// reconstruct on ([grid], or PLUS's automatic extent).
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "core/grid.hpp"
#include "formats/plus_config.hpp"
#include "formats/posed_sequence.hpp"
#include "formats/sequence_io.hpp"
#include "reconstruction/fan_mask.hpp"
#include "reconstruction/reconstruction.hpp"

namespace pp5 {
class ConfigSchema;
}

namespace pp5::gp {

// [grid]: the reconstruction grid (also the grid of the simulated truth volume).
struct GridSettings {
  bool autoExtent = true;        // fit the grid around the sweep (PLUS's rule)
  glm::dvec3 origin{0.0};        // centre of voxel 0, mm (when auto_extent = false)
  glm::dvec3 spacing{1.0};       // mm
  glm::ivec3 dims{256, 256, 256};
  double marginMm = 2.0;         // added around an automatic extent
  double memoryLimitGiB = 0.0;   // 0 = what the machine has available

  std::uint64_t memoryLimitBytes() const {
    return static_cast<std::uint64_t>(memoryLimitGiB * 1024.0 * 1024.0 * 1024.0);
  }
  // The grid of origin, spacing and dims (what auto_extent = false asks for).
  Grid fixedGrid() const;
};
void registerOptions(ConfigSchema& schema, GridSettings& s);

struct ReconRunStats {
  std::uint64_t frames = 0;    // in the file
  std::uint64_t inserted = 0;
  std::uint64_t skipped = 0;   // not placeable (see PosedSequence)
  std::uint64_t notSelected = 0;  // left out by skip_interval or the caller's filter
  double seconds = 0.0;
};

// Inserts the selected frames in file order. `keep(i)` (when set) further
// selects frames (e.g. the leave-out protocol). Progress goes to the log about
// once a second when there is more than a few seconds of work.
ReconRunStats runReconstruction(PosedSequence& seq, Reconstructor& recon,
                                const std::function<bool(std::uint64_t)>& keep = {});

// InputError naming the frame when one pose lies far from all the others (a
// tracker glitch that would stretch the automatic extent to it).
void checkNoOutlierPose(const PosedSequence& seq);

// The clip rectangle and fan as pixel runs, for the frames' size (computed again
// only when the size changes).
class FrameRuns {
 public:
  explicit FrameRuns(const ReconSettings& rs) : rs_(rs) {}
  const std::vector<PixelRun>& of(const Frame& f) {
    if (f.width != width_ || f.height != height_) {
      runs_ = pixelRuns(f.width, f.height, rs_);
      width_ = f.width;
      height_ = f.height;
    }
    return runs_;
  }

 private:
  const ReconSettings& rs_;
  std::vector<PixelRun> runs_;
  int width_ = -1, height_ = -1;
};

// The grid a run uses: OutputOrigin/OutputExtent when the PLUS config gives
// both (PLUS's own tool ignores them; pp5echo honours them), otherwise PLUS's
// automatic extent over every placeable frame, grown by `marginMm`.
Grid chooseGrid(const PosedSequence& seq, const ReconSettings& s, const Vec3& spacing, double marginMm,
                bool useConfigExtent);

// The grid `reconstruct`, `evaluate leave-out` and a run of a sequence reconstruct on: with TOML
// settings (`toml`), [grid]'s fixed grid, or PLUS's rule around the sweep grown
// by grid.margin_mm; with a PLUS config alone (nullptr), chooseGrid at its
// OutputSpacing `plusSpacing` with no margin.
Grid commandGrid(const PosedSequence& seq, const ReconSettings& s, const GridSettings* toml, const Vec3& plusSpacing);

}  // namespace pp5::gp
