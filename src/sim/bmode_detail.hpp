#pragma once
// What sim/bmode.cpp and sim/bmode_render.cpp share: the beam model's
// constants, and the frame's geometry and scratch. Not for other files;
// the constants in an unnamed namespace, as they were in the one file.
#include <vector>

#include "sim/bmode.hpp"

namespace pp5::sim {

namespace {

constexpr double kFwhmToSigma = 1.0 / 2.3548200450309493;  // 2 sqrt(2 ln 2)
constexpr double kPsfCutoff = 3.0;            // PSF and beam profiles end at 3 sigma
constexpr double kMinStepMm = 0.02;           // thinnest feature the beam tracer is sure to see
constexpr double kBoundaryTolMm = 1e-3;       // where a found boundary is placed
constexpr double kDiffuseFloor = 0.03;        // rough-surface echo left at grazing incidence
constexpr double kMinRimCos = 0.25;           // a rim is at most 4x thicker along an oblique beam
constexpr double kMaskDy = 1.0;               // depth blocks of the "any scatterers here" mask, mm
constexpr double kBelowNoiseDb = 40.0;        // scatterers this far below the noise are not simulated

}  // namespace

struct BModeSimulator::FrameGeometry {
  Vec3 origin;  // world position of pixel (0, 0)
  Vec3 u, v, n;  // unit lateral, axial, elevation directions
};

struct BModeSimulator::Workspace {
  int cols = 0;                  // width + 2 * guard
  std::vector<float> re, im;     // complex echo sum, subRows x cols
  std::vector<float> echo;       // per column, per fine row: backscatter amplitude x transmission
  std::vector<float> trans;      // per column, per fine row: two-way transmission
  std::vector<std::uint8_t> mask;  // per column, per mask block: any scatterers
  int maskRows = 0;
  std::vector<float> rowSum;     // envelope summed over an image row's sub-rows
};

}  // namespace pp5::sim
