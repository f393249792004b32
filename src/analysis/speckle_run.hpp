#pragma once
// Shared by `evaluate speckle` and, where recon.kernel_from_frames is on, by
// `reconstruct` and `evaluate truth|leave-out`: the resolution cell a PLUS
// sequence's frames show (analysis/speckle_cell.hpp), and the tent kernel derived
// from it and from the frames' spacing.
#include <cstdint>
#include <functional>
#include <string>

#include "reconstruction/recon_run.hpp"
#include "core/config.hpp"
#include "analysis/speckle_cell.hpp"

namespace pp5::gp {

struct SpeckleRun {
  SpeckleCell cell;
  std::size_t pairsAvailable = 0;  // pairs of consecutive frames (of those used) that can both be placed
  double frameSpacingMm = 0.0;     // median distance between consecutive image centres, over every pair
  glm::dvec2 pixelMm{0.0};         // the first measured frame's pixel size
  double independentCells = 0.0;   // about how many speckle cells the estimate rests on
};

// Measures at most `maxPairs` pairs of consecutive frames, spread over the
// recording, and the triples around them; `use(i)` (when set) selects the
// frames, and "consecutive" is among the selected ones that can be placed
// (what a reconstruction of those frames is given). Reads the file once more from the
// start; `seq`'s own reader is left where it is. InputError when no pair can
// be placed or none shows speckle; a log warning when the estimate rests on
// fewer than a thousand cells.
SpeckleRun measureSpeckle(const PosedSequence& seq, const ReconSettings& rs, int maxPairs, int maxLag,
                          const std::function<bool(std::uint64_t)>& use = {});

// Where rs.tent.kernelFromFrames is on: measures the frames that `use` selects
// (by default every rs.skipInterval-th, as runReconstruction inserts them;
// as measureSpeckle, 32 pairs, lags to 64 px) and sets each tent half-width
// that `schema` says no file or override assigned to kernelFromCell's;
// prints what it measured and derived. InputError when the method is not the
// tent or the cell cannot be measured. Does nothing when the option is off.
// `insertedPixelScale`: how much larger the pixels the reconstruction is given
// are than the recording's (a run's subsampling); the in-plane half-widths are
// at least twice that pixel, as they are twice the recording's.
void deriveKernelFromFrames(const PosedSequence& seq, ReconSettings& rs, const ConfigSchema& schema,
                            const std::function<bool(std::uint64_t)>& use = {},
                            glm::dvec2 insertedPixelScale = glm::dvec2(1.0));

}  // namespace pp5::gp
