#pragma once
// Everything a pp5echo run can be configured with, one struct per TOML section.
// Each module registers its own section; registerAll() puts them together, and
// the same schema parses files and writes docs/configuration.md.
#include <string>

#include "core/config.hpp"
#include "core/enum_names.hpp"
#include "core/grid.hpp"
#include "core/render_settings.hpp"
#include "core/transfer_function.hpp"
#include "reconstruction/recon_run.hpp"
#include "reconstruction/reconstruction.hpp"
#include "rendering/shading.hpp"
#include "host/acquisition.hpp"
#include "host/igtl_serve_settings.hpp"
#include "outputs/live_view.hpp"
#include "outputs/slices.hpp"
#include "pipeline/parallel_settings.hpp"
#include "rendering/ray_cache.hpp"
#include "sim/sim_settings.hpp"
#include "sim/sweep_cache.hpp"

namespace pp5::app {

using gp::GridSettings;

// [output]
struct OutputSettings {
  std::string dir = "out/doll";  // where results go, unless -o says otherwise
  int previewFrames = 4;         // frames written as PNG by `simulate`
};

// What the board's stream does when the board is unplugged.
enum class OnUnplug { End, Wait };
// What `pp5echo run` streams.
enum class SourceKind { Simulator, Sequence, Board, Igtl };

// [board]: the USB interface board (run.source = "board").
struct BoardSettings {
  int vendorId = 0x1209, productId = 0x0001;
  int transferKiB = 256;
  int transfers = 8;
  int queueFrames = 32;
  host::DropPolicy drop = host::DropPolicy::Oldest;
  double frameRate = 0.0;           // > 0: ask the board for this rate
  glm::ivec2 windowOrigin{0, 0};    // capture window; size 0 0 = the whole frame
  glm::ivec2 windowSize{0, 0};
  double openTimeoutS = 5.0;
  double transferTimeoutS = 2.0;
  OnUnplug onUnplug = OnUnplug::End;
  double reconnectTimeoutS = 10.0;
  std::string transform = "ProbeToTracker";  // the per-frame transform the pose becomes
  // The arm's calibration: rows "COUNT VALUE"; empty = the simulator's linear converters ([sim.arm]).
  std::vector<std::string> armXTable, armYTable, armThetaTable;
  double armProbeZMm = 0.0;
  std::uint64_t maxFrameBytes = 16u << 20;  // larger headers are rejected
};

// [run]: what `pp5echo run` streams and which outputs it writes.
struct RunSettings {
  SourceKind source = SourceKind::Simulator;
  std::string igtlUrl = "igtl://127.0.0.1:18944";  // run.source = "igtl"
  double igtlReconnectS = 10.0;      // the server went away: wait this long for it (0 = end at once)
  std::string record;                // write every acquired frame to this PLUS sequence
  std::string sequence;              // run.source = "sequence": the PLUS sequence ...
  std::string plusConfig;            // ... and its PLUS device-set XML (calibration)
  // run.source = "simulator": simulate each frame as it streams (the
  // simulator on the host's path), or the sweep once into the cache folder
  // (sim/sweep_cache.hpp), streamed from there.
  bool simulateLive = false;
  std::string sweepCache;  // "" = $XDG_CACHE_HOME/pp5echo/sweeps or ~/.cache/pp5echo/sweeps
  int buildupEvery = 1;              // every n-th frame goes into the build-up animation
  double buildupFps = 15.0;
  int orbitFrames = 36;              // frames of the rotating movie loop; 0 = none
  double orbitFps = 12.0;
  bool mpr = true;                   // three orthogonal slices through the volume
  host::SliceLook mprLook;           // ... at this size, window and level
  bool volume = true;                // the reconstructed volume as .mha
  // Scripted control changes: "AFTER_FRAME key = value; key = value".
  std::vector<std::string> script;
  // Preprocessing on the host: crop (size 0 0 = none), then subsample.
  glm::ivec2 cropOrigin{0, 0};
  glm::ivec2 cropSize{0, 0};
  int subsample = 1;
  // Acquisition: pace_fps > 0 delivers frames at that rate like a live scanner,
  // dropping by `drop` when the pipeline falls behind.
  double paceFps = 0.0;
  double captureIntervalMm = 0.0;  // constant-interval capture on the host; 0 = every frame
  int queueFrames = 8;
  host::DropPolicy drop = host::DropPolicy::Oldest;
};

struct Settings {
  sim::SimSettings sim;
  BoardSettings board;
  GridSettings grid;
  gp::ReconSettings recon;
  RenderSettings render;
  gp::ShadeSettings shading;
  TransferFunctionSettings tf;
  pp::RayCacheSettings cache;
  RunSettings run;
  parallel::ParallelSettings parallel;
  OutputSettings output;
  host::ViewSettings view;
  host::IgtlServeSettings igtl;
};

void registerAll(ConfigSchema& schema, Settings& s);

// The grid of a simulated sweep: around every frame's reported pose (as a
// reconstruction of the recorded sequence would fit it) plus the margin, or
// the fixed grid when grid.auto_extent is false.
Grid sweepGrid(const Settings& s, const sim::SweepSimulator& sim);
// The same, as the function the sweep cache (sim/sweep_cache.hpp) asks.
sim::SweepGrid sweepGridOf(const Settings& s);

// Creates the output folder (and its parents); InputError when it cannot.
void makeOutputDir(const std::string& dir);

// Defaults, then the file (if any), then `key=value` overrides, in that order.
void loadSettings(ConfigSchema& schema, const std::string& file, const std::vector<std::string>& overrides);
// The settings alone, for commands that do not write them back out.
Settings readSettings(const std::string& file, const std::vector<std::string>& overrides);

}  // namespace pp5::app

namespace pp5 {

template <>
struct EnumNames<app::OnUnplug> {
  static constexpr std::string_view key = "board.on_unplug";
  static constexpr std::array<std::pair<app::OnUnplug, std::string_view>, 2> names{{
      {app::OnUnplug::End, "end"},
      {app::OnUnplug::Wait, "wait"}}};
};

template <>
struct EnumNames<app::SourceKind> {
  static constexpr std::string_view key = "run.source";
  static constexpr std::array<std::pair<app::SourceKind, std::string_view>, 4> names{{
      {app::SourceKind::Simulator, "simulator"},
      {app::SourceKind::Sequence, "sequence"},
      {app::SourceKind::Board, "board"},
      {app::SourceKind::Igtl, "igtl"}}};
};

}  // namespace pp5
