#pragma once
// The simulated sweep as a PLUS sequence: what `pp5echo bench` streams to
// every layout, and what `pp5echo run` streams by default with
// run.source = "simulator" (run.simulate_live = false). A real scanner
// delivers frames at its own rate whatever the computer does; simulating a
// B-mode frame costs the host's core tens of milliseconds, so the default run
// simulates the sweep once, keeps it in a cache folder keyed by everything
// that shaped it, and streams it at run.pace_fps like a recording.
#include <cstddef>
#include <functional>
#include <string>

#include "core/grid.hpp"
#include "sim/sim_settings.hpp"

namespace pp5::sim {

class SweepSimulator;
// The grid a sweep is reconstructed on, written into its device-set XML (the
// command line's [grid] around the simulated poses).
using SweepGrid = std::function<Grid(const SweepSimulator&)>;

struct SimulatedSweep {
  std::string sequencePath, configPath;
  std::string firstPath;      // the sweep's first frame alone (the bench's baseline runs)
  std::size_t frames = 0;
  double maxPoseError = 0.0;  // mm, largest |element| of ImageToReference read back minus simulated
  double simulateS = 0.0;     // 0 when it came from the cache
  bool fromCache = false;
};

// Simulates the sweep of `s` into `dir` (created): the sequence (uncompressed,
// so a host pays only for reading it), the device-set XML with ImageToProbe
// and the sweep grid as its VolumeReconstruction element, and the first
// frame alone. Reads the sequence back as run.source = "sequence" does and
// requires the simulator's pixels, indices and times, and poses within 1e-6 mm
// (InvariantError otherwise).
SimulatedSweep simulateSweep(const SimSettings& s, const SweepGrid& grid, const std::string& dir);

// What identifies a simulated sweep: every sim.* setting but sim.threads
// (which does not change a frame), and the program that simulates it (its
// size and modification time, so a rebuilt simulator simulates anew). A
// 16-digit hexadecimal hash.
std::string sweepCacheKey(const SimSettings& s);

// The folder of cached sweeps: `configured` (run.sweep_cache) when set, else $XDG_CACHE_HOME/pp5echo/
// sweeps, else $HOME/.cache/pp5echo/sweeps.
std::string sweepCacheFolder(const std::string& configured);

// The sweep for `s` from the cache in sweepCacheFolder(folder), simulated into it first when missing.
// Runs that race for the same key each simulate into their own temporary
// folder; the first rename wins and the others use its copy. From the cache,
// `frames`, `maxPoseError` and `simulateS` are 0 (they were checked when it
// was written). The config's VolumeReconstruction element holds the grid of
// the run that filled the cache; a run passes its own grid (sweepGrid), so
// [grid] is not part of the key. InputError when the folder cannot be made.
SimulatedSweep cachedSweep(const SimSettings& s, const SweepGrid& grid, const std::string& folder);

}  // namespace pp5::sim
