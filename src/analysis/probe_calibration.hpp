#pragma once
// ImageToProbe from an N-wire phantom: where each frame's image plane cuts the
// middle wires is known in the Phantom frame from the dots' spacing alone
// (analysis/nwire.hpp), and the tracker gives PhantomToProbe per frame, so the
// pixel of each middle dot has a known place in the Probe frame. A linear least
// squares fit of those pairs, with points beyond mean + 2 sd rejected and the
// fit repeated, gives the start; a refinement then minimises the mean 3D
// reprojection error itself, or every dot's distance from where it belongs
// (the outer wires' lines too), over an affine or a rigid-plus-scale
// ImageToProbe.
#include <cstddef>
#include <string>
#include <vector>

#include "analysis/nwire.hpp"
#include "core/transform.hpp"

namespace pp5::calib {

// One frame whose pattern was found: its dots (per pattern, left to right in
// the image, as segmentWires gives them) and the tracked PhantomToProbe.
struct CalibrationFrame {
  std::size_t frameIndex = 0;  // in the recording
  Mat4 phantomToProbe{1.0};
  std::vector<PatternDots> dots;
};

enum class CalibrationModel {
  Affine,      // a 3x4 affine on the image plane (PLUS's fCal result): 9 parameters
  RigidScale,  // a rotation, a translation and a mm-per-pixel scale per image axis: 8
};

// What the refinement after the linear fit minimises.
enum class CalibrationRefinement {
  None,          // the linear fit alone (its squared middle-wire distances), as PLUS's first step
  MeanDistance,  // the mean 3D reprojection error of the middle wires itself (PLUS's figure),
                 // by iteratively reweighted least squares
  AllWires,      // every dot's squared distance: the outer ones from their wires' lines, the
                 // middle ones from where the ratio places them (all nine wires)
};

// The defaults were chosen on simulated sweeps with a known calibration
// (docs/calibration.md, "Choosing the defaults").
struct CalibrationOptions {
  CalibrationModel model = CalibrationModel::RigidScale;
  CalibrationRefinement refinement = CalibrationRefinement::AllWires;
  double outlierSd = 2.0;  // reject points beyond mean + outlierSd * sd of the distances
  int outlierRounds = 3;   // at most this many reject-and-refit rounds
  int minFrames = 10;      // fewer frames with the pattern found: an error
};

// The 3D reprojection error of the middle wires (PLUS's figure): the distance,
// in the Probe frame, between a middle dot mapped through ImageToProbe and
// where the ratio places it on its wire.
struct ReprojectionError {
  double mean = 0.0, sd = 0.0, rms = 0.0, max = 0.0;
  std::size_t points = 0;
  std::vector<double> meanPerPattern;  // one per pattern
};

struct CalibrationResult {
  Mat4 imageToProbe{1.0};
  // Which end of each line is wire 0: false for the leftmost dot in the image.
  // Chosen once for the recording, by the linear fit's residual.
  bool wire0OnRight = false;
  std::size_t frames = 0;           // frames used
  std::size_t pointsRejected = 0;   // middle-wire points the linear fit rejected as outliers
  std::size_t dotsRejected = 0;     // dots the all-wires refinement rejected as outliers
  double conditionNumber = 0.0;     // of the linear fit's (normalised) design
  double rotationSpreadDeg = 0.0;   // largest angle between a frame's PhantomToProbe and the first's
  double translationSpreadMm = 0.0; // largest distance between the phantom's origin in two frames' Probe
  Mat4 linearImageToProbe{1.0};     // the linear fit alone (before the refinement)
  ReprojectionError linearError;    // on the frames used, after the linear fit
  ReprojectionError error;          // on the frames used, final
  double wireDistanceRms = 0.0;     // RMS distance of every dot from its wire's line or middle point (in use)
};

// Fits ImageToProbe. Throws InputError when the frames cannot determine it:
// fewer than options.minFrames, too little motion of the probe, or a
// singular fit; the message says what to record instead.
CalibrationResult calibrateProbe(const NWirePhantom& phantom, const std::vector<CalibrationFrame>& frames,
                                 const CalibrationOptions& options = {});

// PLUS's 3D reprojection error of the middle wires for `imageToProbe` over
// `frames` (the frames used, or held-out ones, or another recording).
ReprojectionError middleWireError(const NWirePhantom& phantom, const std::vector<CalibrationFrame>& frames,
                                  const Mat4& imageToProbe, bool wire0OnRight);

// Per wire (pattern k's wire w at index 3 k + w), the mean distance of its
// dots mapped through `imageToProbe` from where they belong: an outer wire's
// line, a middle wire's ratio point (so the middle wires' entries are PLUS's
// figure per wire).
std::vector<double> wireErrors(const NWirePhantom& phantom, const std::vector<CalibrationFrame>& frames,
                               const Mat4& imageToProbe, bool wire0OnRight);

// The largest distance between where two ImageToProbe put the corners and the
// centre of a w x h image (mm).
double cornerDistanceMm(const Mat4& a, const Mat4& b, int width, int height);

}  // namespace pp5::calib
