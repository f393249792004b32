#pragma once
// The graphics-processor rank: frames in from the host, ray samples out to the
// pixel processors. It calls the same stages as the serial pipeline
// (pipeline/serial_pipeline.hpp), restricted to its share of the work:
//  - slab: it reconstructs only its window of the grid (its cells plus ghost
//    layers), shades the voxels its cells' samples read, and samples only the
//    lattice points of its cells;
//  - tile: it reconstructs the whole grid, shades only the bricks its own
//    screen tiles can see, and samples only the rays of those tiles.
// Either way every sample it sends has the bits the serial pipeline computes.
#include <cstdint>

#include "pipeline/parallel_settings.hpp"
#include "pipeline/schedule.hpp"
#include "comm/transport.hpp"
#include "core/grid.hpp"
#include "core/render_settings.hpp"
#include "formats/sample_runs.hpp"
#include "core/transfer_function.hpp"
#include "reconstruction/reconstruction.hpp"
#include "rendering/shading.hpp"

namespace pp5::ranks {

struct GpRankConfig {
  Grid grid;
  gp::ReconSettings recon;
  RenderSettings render;
  gp::ShadeSettings shading;
  TransferFunctionSettings tf;
  parallel::ParallelSettings parallel;
  pp5::parallel::RankLayout layout;
  std::uint64_t memoryLimitBytes = 0;
  // The samples' wire form: half where the PPs' caches store half
  // (pp::sampleWireFor(render.cache.format)).
  SampleWire wire = SampleWire::Half;
};

// Runs until the host says quit; throws on any error (the caller ends the job).
void runGpRank(comm::Transport& t, const GpRankConfig& c);

}  // namespace pp5::ranks
