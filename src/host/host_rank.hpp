#pragma once
// The host rank (rank 0) of the distributed pipeline: it runs the source in
// an acquisition thread, sends frames to the graphics processors under
// credit-based flow control (slab: pixels only to the GPs a frame can reach),
// broadcasts control changes with new epochs, assembles the pixel
// processors' tiles into the frame buffer, and writes what the serial run
// writes, plus per-rank statistics and a summary.
#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "comm/messages.hpp"
#include "parallel/parallel_settings.hpp"
#include "comm/transport.hpp"
#include "host/acquisition.hpp"
#include "host/live_view.hpp"
#include "host/slices.hpp"
#include "serial/serial_pipeline.hpp"

namespace pp5::host {

// A control change scripted by frame: applied after that frame is sent.
struct ScriptedControl {
  std::uint64_t afterFrame = 0;  // stream position (0 = after the first frame)
  comm::ControlState state;
  std::string text;              // as written in run.script, for messages
};

struct HostJob {
  Grid grid;
  serial::PipelineSettings pipeline;
  parallel::ParallelSettings parallel;
  parallel::RankLayout layout;
  Source source;
  Preprocess preprocess;
  std::size_t queueFrames = 8;
  DropPolicy drop = DropPolicy::Oldest;
  double paceFps = 0.0;
  double captureIntervalMm = 0.0;  // run.capture_interval_mm
  std::vector<ScriptedControl> script;

  std::string outDir;
  int buildupEvery = 1;
  double buildupFps = 15.0;
  int orbitFrames = 36;
  double orbitFps = 12.0;
  bool mpr = true, volume = true;
  SliceLook mprLook;
  // Run the serial pipeline beside the distributed one and require every
  // image to be bitwise equal (needs parallel.composite_on = lockstep).
  bool verify = false;
  std::uint64_t memoryLimitBytes = 0;
  // The live viewer ([view]; view.listen "" = none).
  ViewSettings view;
  // Set from a signal handler: stop acquiring, finish what was acquired.
  const std::atomic<bool>* interrupt = nullptr;
};

// Applies a control change to a serial pipeline, as the GPs and PPs apply it
// to their shares (the reference run beside the distributed one, and the
// serial run's live viewer).
void applyControl(serial::SerialPipeline& pipe, std::uint32_t changes, const comm::ControlState& next,
                  const RenderSettings& base, const Grid& grid);

// Runs the job; returns the process exit status. Throws on errors (the caller
// ends the job with the message).
int runHostRank(comm::Transport& t, const HostJob& job);

}  // namespace pp5::host
