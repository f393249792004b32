#pragma once
// The pixel-processor rank: ray samples in from the graphics processors, the
// changed tiles of the image out to the host. It holds one hierarchical
// ray-sample cache (rendering/ray_cache.hpp) per screen tile it owns.
//
// An update (a frame, or the full re-sample after a control change) is
// complete when every GP's GpDone for it has arrived; messages from one GP
// arrive in the order it sent them, so its samples come before its GpDone.
//  - lockstep: each update is applied whole, in order, once complete, then
//    composited and sent: the image after every frame equals the serial one.
//  - tick: samples go into the caches as they arrive; a clock (parallel.tick_hz)
//    recomposites the dirty blocks and rays and sends the tiles that changed.
// A control change from the host is applied at once: messages from older
// epochs still in flight are dropped (counted), and those from the new epoch
// that overtook the control wait for it.
#include "pipeline/parallel_settings.hpp"
#include "pipeline/schedule.hpp"
#include "comm/transport.hpp"
#include "core/grid.hpp"
#include "core/render_settings.hpp"
#include "rendering/shading.hpp"
#include "rendering/ray_cache.hpp"

namespace pp5::ranks {

struct PpRankConfig {
  Grid grid;
  RenderSettings render;
  gp::ShadeSettings shading;
  TransferFunctionSettings tf;
  pp::RayCacheSettings cache;
  parallel::ParallelSettings parallel;
  pp5::parallel::RankLayout layout;
};

// Runs until the host says quit; throws on any error (the caller ends the job).
void runPpRank(comm::Transport& t, const PpRankConfig& c);

}  // namespace pp5::ranks
