#pragma once
// Finding an N-wire phantom's dots in a B-mode frame (fCal's segmentation,
// reworked): a grey opening with a disc removes speckle smaller than a wire's
// dot, a threshold keeps the bright blobs, and each blob's intensity-weighted
// centroid is a candidate. The brightest candidates are grouped into
// collinear triples, and one triple per pattern is chosen so that the lines
// lie in the patterns' order from the probe face down, nearly parallel, as far
// apart as the patterns' planes and as long as their outer wires are apart.
// Every tolerance comes from the config's <Segmentation> element.
#include <cstdint>
#include <string>
#include <vector>

#include "analysis/nwire.hpp"
#include "core/frame.hpp"
#include "formats/plus_config.hpp"

namespace pp5::calib {

struct DotCandidate {
  Vec2 position;       // intensity-weighted centroid, pixels of the whole frame
  double score = 0.0;  // summed intensity of the blob
  int area = 0;        // pixels
};

struct WireSegmentation {
  std::vector<DotCandidate> candidates;  // best first, at most NumberOfMaximumFiducialPointCandidates
  int collinearTriples = 0;              // candidate lines found
  bool found = false;
  // When found: one entry per pattern, the dots in the order of their image x
  // (left to right). Which end is wire 0 is the calibration's choice
  // (analysis/probe_calibration.hpp), the same for every frame of a recording.
  std::vector<PatternDots> patterns;
  std::string why;  // when not found: what was missing
};

// A grey-level opening (erosion, then dilation) of a w x h 8-bit image with a
// disc of radius `radius` pixels (radius 0: a copy). Exposed for tests.
std::vector<std::uint8_t> openWithDisc(const std::vector<std::uint8_t>& image, int w, int h, int radius);

// Segments one 8-bit frame. Throws InputError for a frame that is not 8-bit.
WireSegmentation segmentWires(const Frame& frame, const PlusSegmentation& settings, const NWirePhantom& phantom);

}  // namespace pp5::calib
