#pragma once
// Settings of the simulated world: which phantom, which probe, how the B-mode
// image is formed, and how the probe moves. One struct per TOML section
// ([sim], [sim.probe], [sim.bmode], [sim.sweep], [sim.arm], [sim.freehand]);
// registerOptions() binds every field to its key with a default, range and doc.
#include <cstdint>
#include <string>

#include <glm/glm.hpp>

namespace pp5 {
class ConfigSchema;
}

namespace pp5::sim {

// [sim.probe]
struct ProbeSettings {
  std::string preset = "paper35";  // paper35 | linear75
  int widthPx = 0;                 // 0 = the preset's
  int heightPx = 0;                // 0 = the preset's
  double depthMm = 0.0;            // imaging depth; 0 = the preset's
};

// [sim.bmode]
struct BModeSettings {
  double dynamicRangeDb = 60.0;
  double gainDb = 0.0;
  double tgcDbPerCmMHz = -1.0;    // < 0: compensate the phantom's background medium
  double noiseDb = -58.0;         // electronic noise, RMS, relative to white
  double scatterersPerCell = 16.0;
  double specularWidthDeg = 12.0;
  // physical: attenuation, interface echoes, transmission loss and shadows;
  // ideal: speckle only, so the expected image is the truth volume (accuracy studies).
  std::string medium = "physical";
};

// [sim.sweep]
struct SweepSettings {
  std::string kind = "parallel";   // parallel | angled | back_and_forth | freehand
  std::string capture = "interval";  // interval | every_frame
  double captureIntervalMm = 2.0;
  double speedMmPerS = 6.0;
  double lengthMm = 0.0;           // 0 = the phantom's
  double frameRateHz = 30.0;
  int passes = 1;                  // parallel: side-by-side passes
  double passSpacingMm = 20.0;
  double angleDeg = 0.0;           // angled: direction of the sweep from the x axis
  int repeats = 3;                 // back_and_forth: one-way passes
  double lateralOffsetMm = 0.0;
  int maxFrames = 0;               // 0 = no limit
};

// [sim.arm]: the 1990 system's 3-DOF arm (x, y, theta through 12-bit A/D).
struct ArmSettings {
  double sampleRateHz = 800.0;
  double noiseCounts = 0.5;
  double xSpanMm = 400.0;          // x travel over counts 0..4095
  double ySpanMm = 300.0;
  double thetaSpanDeg = 180.0;     // centred on 0
  glm::dvec3 referenceToTrackerMm{200.0, 150.0, 0.0};
};

// [sim.freehand]: the 6-DOF hand-held path and its tracker.
struct FreehandSettings {
  double driftMm = 3.0;
  double heaveMm = 1.0;
  double tiltDeg = 5.0;
  double rollDeg = 3.0;
  double yawDeg = 3.0;
  double tremorMm = 0.15;
  double tremorDeg = 0.2;
  double trackerNoiseMm = 0.1;
  double trackerNoiseDeg = 0.05;
};

// [sim]
struct SimSettings {
  std::uint64_t seed = 1;
  std::string phantom = "doll";    // doll | forearm | wires
  std::string truthType = "float32";  // float32 | uint8
  int threads = 0;                 // 0 = every core
  ProbeSettings probe;
  BModeSettings bmode;
  SweepSettings sweep;
  ArmSettings arm;
  FreehandSettings freehand;
};

void registerOptions(ConfigSchema& schema, SimSettings& s);

}  // namespace pp5::sim
