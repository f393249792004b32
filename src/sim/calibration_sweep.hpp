#pragma once
// A simulated probe calibration: the N-wire phantom of a PLUS config
// (<PhantomDefinition>, placed by its Phantom to Reference transform) imaged
// by a linear probe that slides along the wires and tilts and turns a few
// degrees each way, with the B-mode model's wire blur and noise, a speckled
// gel base under the wires, and tracker noise on the reported poses. The
// true ImageToProbe is known, so a calibration can be scored against it.
#include <cstdint>
#include <vector>

#include "core/frame.hpp"
#include "formats/plus_config.hpp"
#include "sim/phantom.hpp"

namespace pp5::sim {

struct CalibrationSweepSettings {
  std::uint64_t seed = 1;
  int frames = 60;
  int widthPx = 820, heightPx = 616;     // the fCal recordings' size
  double widthMm = 64.0, depthMm = 46.0;  // about 0.078 mm per pixel, as theirs
  double trackerNoiseMm = 0.1;           // sd of each translation component
  double trackerNoiseDeg = 0.1;          // sd of the rotation about each axis
  double slideMm = 26.0;                 // travel along the wires
  double tiltDeg = 8.0;                  // largest tilt or turn about each probe axis
};

struct CalibrationSweep {
  std::vector<Frame> frames;  // ProbeToTracker (with noise), ReferenceToTracker, TrueProbeToTracker
  Mat4 imageToProbe{1.0};     // the truth
  double mmPerPixel = 0.0;    // the image's spacing (the same along both axes)
};

// The phantom's wires as the simulator's line targets, in the Reference
// frame, above a scattering gel base.
Phantom makeNWirePhantom(const PlusPhantomDefinition& def, const Mat4& phantomToReference);

// Renders the sweep on `threads` threads (0 = every core). The frames do not
// depend on the thread count.
CalibrationSweep simulateCalibrationSweep(const PlusPhantomDefinition& def, const Mat4& phantomToReference,
                                          const CalibrationSweepSettings& settings, int threads = 0);

}  // namespace pp5::sim
