#pragma once
// A whole calibration recording: every frame segmented (in parallel, in
// batches, so only a batch of frames is held at once), with its tracked
// PhantomToProbe from the sequence's transforms and the config's fixed ones.
#include <cstddef>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "analysis/nwire.hpp"
#include "analysis/probe_calibration.hpp"
#include "analysis/wire_segmentation.hpp"
#include "core/frame.hpp"
#include "formats/plus_config.hpp"

namespace pp5::calib {

struct SegmentedRecording {
  std::string path;
  int width = 0, height = 0;
  std::size_t frames = 0;                  // in the file
  std::vector<CalibrationFrame> found;     // frames whose pattern was found, in order
  // Frames left out, with why: an invalid image or pose, or the pattern not found.
  std::vector<std::pair<std::size_t, std::string>> missed;
};

// The phantom of a config; InputError naming the file when it has no
// <PhantomDefinition> or <Segmentation>.
NWirePhantom phantomOf(const PlusConfig& cfg);

// PhantomToProbe of one frame: its tracked transforms with the config's fixed
// ones; nullopt when a transform on the chain is missing or INVALID.
std::optional<Mat4> phantomToProbe(const PlusConfig& cfg, const Frame& frame);

// Segments every frame of `path`. `onFrame(frame, segmentation)` (optional) is
// called for every frame in order, on the calling thread; `progress(done,
// total)` after each batch. Throws InputError when the recording is not 8-bit
// or the config cannot place the Phantom in the Probe frame.
SegmentedRecording segmentRecording(const std::string& path, const PlusConfig& cfg, int threads,
                                    const std::function<void(const Frame&, const WireSegmentation&)>& onFrame = {},
                                    const std::function<void(std::size_t, std::size_t)>& progress = {});

}  // namespace pp5::calib
