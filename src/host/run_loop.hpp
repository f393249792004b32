#pragma once
// The one run loop of `pp5echo run`, in one process and under mpirun alike:
// it runs the source in the acquisition thread, feeds the pipeline frame by
// frame, applies run.script's changes and the viewer's, pauses and stops on
// Ctrl-C, shows progress, and after the input makes the final passes, the
// final images per mode, the volume and the orbit, handing each to the sinks
// (host/sink.hpp). Which pipeline it drives (host/pipeline.hpp) is the only
// difference between the two modes.
#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "host/igtl_serve_settings.hpp"
#include "host/acquisition.hpp"
#include "host/pipeline.hpp"
#include "host/sink.hpp"
#include "host/view_settings.hpp"
#include "pipeline/parallel_settings.hpp"
#include "pipeline/schedule.hpp"
#include "pipeline/serial_pipeline.hpp"

namespace pp5::host {

// A control change scripted by frame: applied after that frame is in.
struct ScriptedControl {
  std::uint64_t afterFrame = 0;  // the source's frame index (0 = after the first frame)
  ViewState state;
  std::string text;  // as written in run.script, for messages
};

// Everything a run needs: the pipeline's settings (the distributed one's
// too), the source and its acquisition, the script, and the outputs.
struct RunJob {
  Grid grid;
  serial::PipelineSettings pipeline;
  parallel::ParallelSettings parallel;  // the distributed pipeline's
  parallel::RankLayout layout;
  Source source;
  Preprocess preprocess;
  std::size_t queueFrames = 8;
  DropPolicy drop = DropPolicy::Oldest;
  double paceFps = 0.0;
  double captureIntervalMm = 0.0;  // run.capture_interval_mm
  std::vector<ScriptedControl> script;

  std::string outDir;
  std::string plusConfig;  // run.plus_config ("" = none): what places a sequence a command reconstructs
  int buildupEvery = 1;
  double buildupFps = 15.0;
  int orbitFrames = 36;
  double orbitFps = 12.0;
  bool mpr = true, volume = true;
  SliceLook mprLook;
  // The distributed pipeline: run the serial pipeline beside it and require
  // every image to be bitwise equal (every image with parallel.composite_on =
  // lockstep; in tick mode those once every frame is in).
  bool verify = false;
  std::uint64_t memoryLimitBytes = 0;
  // The one-process pipeline: where each frame's work lies, written here ("" = not counted).
  std::string census;
  // The live viewer ([view]; view.listen "" = none).
  ViewSettings view;
  // The OpenIGTLink server (run.igtl_serve "" = none).
  IgtlServeSettings igtl;
  // Files the run writes beside the sinks' (settings.toml), for the closing list.
  std::vector<std::string> alsoWrote;
  // Set from a signal handler: stop acquiring, finish what was acquired.
  const std::atomic<bool>* interrupt = nullptr;
};

// Applies a control change to a serial pipeline, as the GPs and PPs apply it
// to their shares; the times of a view change's full re-render.
serial::ViewStats applyControl(serial::SerialPipeline& pipe, std::uint32_t changes, const ViewState& next,
                  const RenderSettings& base, const Grid& grid);

// Runs the job through `pipeline`, every sink given what it wants; returns
// the exit status. Throws on errors (the caller ends the run with the
// message).
int runLoop(Pipeline& pipeline, const RunJob& job, const std::vector<Sink*>& sinks);
// A pipeline over a whole volume (no source): the sinks get it, and the
// steering sink steers it until Ctrl-C (`pp5echo view`).
void serveVolume(Pipeline& pipeline, const RunJob& job, const std::vector<Sink*>& sinks);

}  // namespace pp5::host
