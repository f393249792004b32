#pragma once
// Settings of the simulated world: which phantom, which probe, how the B-mode
// image is formed, and how the probe moves. One struct per TOML section
// ([sim], [sim.probe], [sim.bmode], [sim.sweep], [sim.arm], [sim.freehand]);
// registerOptions() binds every field to its key with a default, range and doc.
#include <cstdint>
#include <string>

#include <glm/glm.hpp>

#include "core/enum_names.hpp"

namespace pp5 {
class ConfigSchema;
}

namespace pp5::sim {

enum class ProbePreset { Paper35, Linear75 };
enum class Medium { Physical, Ideal };
enum class SweepKind { Parallel, Angled, BackAndForth, Freehand };
enum class Capture { Interval, EveryFrame };
enum class PhantomKind { Doll, Forearm, Wires };
enum class TruthType { Float32, Uint8 };

// [sim.probe]
struct ProbeSettings {
  ProbePreset preset = ProbePreset::Paper35;
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
  Medium medium = Medium::Physical;
};

// [sim.sweep]
struct SweepSettings {
  SweepKind kind = SweepKind::Parallel;
  Capture capture = Capture::Interval;
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
  PhantomKind phantom = PhantomKind::Doll;
  TruthType truthType = TruthType::Float32;
  int threads = 0;                 // 0 = every core
  ProbeSettings probe;
  BModeSettings bmode;
  SweepSettings sweep;
  ArmSettings arm;
  FreehandSettings freehand;
};

void registerOptions(ConfigSchema& schema, SimSettings& s);

}  // namespace pp5::sim

namespace pp5 {

template <>
struct EnumNames<sim::ProbePreset> {
  static constexpr std::string_view key = "sim.probe.preset";
  static constexpr std::array<std::pair<sim::ProbePreset, std::string_view>, 2> names{{
      {sim::ProbePreset::Paper35, "paper35"},
      {sim::ProbePreset::Linear75, "linear75"}}};
};

template <>
struct EnumNames<sim::Medium> {
  static constexpr std::string_view key = "sim.bmode.medium";
  static constexpr std::array<std::pair<sim::Medium, std::string_view>, 2> names{{
      {sim::Medium::Physical, "physical"},
      {sim::Medium::Ideal, "ideal"}}};
};

template <>
struct EnumNames<sim::SweepKind> {
  static constexpr std::string_view key = "sim.sweep.kind";
  static constexpr std::array<std::pair<sim::SweepKind, std::string_view>, 4> names{{
      {sim::SweepKind::Parallel, "parallel"},
      {sim::SweepKind::Angled, "angled"},
      {sim::SweepKind::BackAndForth, "back_and_forth"},
      {sim::SweepKind::Freehand, "freehand"}}};
};

template <>
struct EnumNames<sim::Capture> {
  static constexpr std::string_view key = "sim.sweep.capture";
  static constexpr std::array<std::pair<sim::Capture, std::string_view>, 2> names{{
      {sim::Capture::Interval, "interval"},
      {sim::Capture::EveryFrame, "every_frame"}}};
};

template <>
struct EnumNames<sim::PhantomKind> {
  static constexpr std::string_view key = "sim.phantom";
  static constexpr std::array<std::pair<sim::PhantomKind, std::string_view>, 3> names{{
      {sim::PhantomKind::Doll, "doll"},
      {sim::PhantomKind::Forearm, "forearm"},
      {sim::PhantomKind::Wires, "wires"}}};
};

template <>
struct EnumNames<sim::TruthType> {
  static constexpr std::string_view key = "sim.truth_type";
  static constexpr std::array<std::pair<sim::TruthType, std::string_view>, 2> names{{
      {sim::TruthType::Float32, "float32"},
      {sim::TruthType::Uint8, "uint8"}}};
};

}  // namespace pp5
