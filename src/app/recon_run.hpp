#pragma once
// Shared by `reconstruct` and `evaluate`: stream a PLUS sequence through a
// reconstructor, with poses from a PLUS config, skipping and counting frames
// that cannot be placed, and showing progress on long input.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "app/settings.hpp"
#include "formats/plus_config.hpp"
#include "formats/posed_sequence.hpp"
#include "formats/sequence_io.hpp"
#include "reconstruction/fan_mask.hpp"
#include "reconstruction/reconstruction.hpp"

namespace pp5::app {

using pp5::PosedSequence;
using pp5::openPosedSequence;

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
ReconRunStats runReconstruction(PosedSequence& seq, gp::Reconstructor& recon,
                                const std::function<bool(std::uint64_t)>& keep = {});

// InputError naming the frame when one pose lies far from all the others (a
// tracker glitch that would stretch the automatic extent to it).
void checkNoOutlierPose(const PosedSequence& seq);

// The clip rectangle and fan as pixel runs, for the frames' size (computed again
// only when the size changes).
class FrameRuns {
 public:
  explicit FrameRuns(const gp::ReconSettings& rs) : rs_(rs) {}
  const std::vector<gp::PixelRun>& of(const Frame& f) {
    if (f.width != width_ || f.height != height_) {
      runs_ = gp::pixelRuns(f.width, f.height, rs_);
      width_ = f.width;
      height_ = f.height;
    }
    return runs_;
  }

 private:
  const gp::ReconSettings& rs_;
  std::vector<gp::PixelRun> runs_;
  int width_ = -1, height_ = -1;
};

// The grid a run uses: OutputOrigin/OutputExtent when the PLUS config gives
// both (PLUS's own tool ignores them; pp5echo honours them), otherwise PLUS's
// automatic extent over every placeable frame, grown by `marginMm`.
Grid chooseGrid(const PosedSequence& seq, const gp::ReconSettings& s, const Vec3& spacing, double marginMm,
                bool useConfigExtent);

// The grid `reconstruct`, `evaluate leave-out` and a run of a sequence reconstruct on: with TOML
// settings (`toml`), [grid]'s fixed grid, or PLUS's rule around the sweep grown
// by grid.margin_mm; with a PLUS config alone (nullptr), chooseGrid at its
// OutputSpacing `plusSpacing` with no margin.
Grid commandGrid(const PosedSequence& seq, const gp::ReconSettings& s, const GridSettings* toml, const Vec3& plusSpacing);

}  // namespace pp5::app
