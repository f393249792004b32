#pragma once
// What `pp5echo bench` (cmd_bench.cpp) and its cost model
// (bench_cost_model.cpp) share: the command lines of their children and the
// MPI ping-pong.
#include <atomic>
#include <string>
#include <vector>

#include "sim/sweep_cache.hpp"
#include "benchmark/cost_model.hpp"
#include "benchmark/layouts.hpp"

namespace pp5::app {

// `mpirun [--mca pml ob1 --mca btl tcp,self] -n RANKS`: Open MPI's TCP
// transport, or the default (shared memory).
std::vector<std::string> mpirunArgv(const std::string& mpirun, bool tcp, int ranks);
// `mpirun [transport] -n N pp5echo run FILE -o DIR --expect-ranks N --set ...`
// for layout l on `sequence` (baseline: no scripted view change).
std::vector<std::string> layoutArgv(const std::string& mpirun, const std::string& exe, const std::string& file,
                                    const std::vector<std::string>& overrides, const std::string& plusConfig,
                                    const harness::Layout& l, const std::string& dir, const std::string& sequence,
                                    bool baseline);
// `pp5echo run FILE --serial -o DIR [--census CENSUS] --set ...`, one thread.
std::vector<std::string> serialArgv(const std::string& exe, const std::string& file,
                                    const std::vector<std::string>& overrides, const sim::SimulatedSweep& seq,
                                    const std::string& dir, const std::string& census);
// Two ranks bounce messages (the hidden `bench --pingpong`); its log goes to dir.
harness::Bandwidth measureBandwidth(const std::string& mpirun, const std::string& exe, const std::string& dir,
                                    bool tcp, const std::atomic<bool>* stop);

struct CostModelRun {
  std::string mpirun, exe, file, outDir;
  std::vector<std::string> overrides;  // the user's --set, after the model's workload settings
  double timeoutS = 150.0;
  const std::atomic<bool>* stop = nullptr;
  bool quick = false;  // fewer layouts: a smoke test
  int repeats = 3;     // runs of each layout (medians)
};
// `pp5echo bench CONFIG --cost-model`: census, fit, predict, run, compare;
// writes cost_model.md and cost_model.csv under outDir. Returns the exit code.
int runCostModel(const CostModelRun& run);

}  // namespace pp5::app
