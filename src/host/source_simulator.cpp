#include <fmt/format.h>

#include "core/error.hpp"
#include "host/sources.hpp"

namespace pp5::host {

Source simulatorSource(std::shared_ptr<sim::SweepSimulator> sim, const Grid& grid, int threads) {
  Source src;
  src.frames = sim->frameCount();
  if (src.frames == 0)
    throw InputError("sim.sweep: the sweep captured no frames; lengthen it or lower sim.sweep.capture_interval_mm");
  const sim::SimSettings& s = sim->settings();
  src.description = fmt::format("simulated {} sweep over the {} phantom, {} probe, {} frames", enumName(s.sweep.kind),
                                enumName(s.phantom), sim->probe().name, src.frames);
  src.grid = grid;
  src.run = [sim, threads](const FrameSink& sink) {
    sim->run(threads, [&](Frame&& f) { sink(f, sim->imageToReference(f.index), f.timestamp); });
  };
  return src;
}

}  // namespace pp5::host
