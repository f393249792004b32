#pragma once
// What `pp5echo run` sets up from its settings before a run (app/cmd_run.cpp
// runs it): the checks every rank makes alike, recon.kernel_from_frames,
// run.script and the job both pipelines run.
#include <atomic>
#include <string>
#include <vector>

#include "app/settings.hpp"
#include "core/config.hpp"
#include "host/run_loop.hpp"

namespace pp5::app {

// run.crop_* and run.subsample (InputError for a crop with one side only).
host::Preprocess preprocessOf(const Settings& s);
// What no stage could honour fails on every rank alike, before any starts
// (and `pp5echo config` refuses the same): the view, the reconstruction, the
// shading, the ray cache, parallel.tile_size, run.script, the board's arm
// tables, an empty output.dir (unless `-o` names the folder).
void checkSettings(const Settings& s, bool outputDirGiven = false);
// Says once (a warning) which assigned settings this run does not use: the
// ranks' layout in a one-process run, the board's in a run of another source.
void warnUnusedSettings(const Settings& s, const ConfigSchema& schema, bool oneProcess);
// recon.kernel_from_frames: the kernel from the recording (run.source =
// "sequence") or the simulator's cached sweep, over the frames the capture
// takes; printed. Where the source is read only (rank 0 under mpirun).
void deriveRunKernel(Settings& s, const ConfigSchema& schema);
// run.script entries: "AFTER_FRAME key = value; key = value" (InputError naming the entry).
std::vector<host::ScriptedControl> parseScript(const Settings& base);
// Whether the run writes DIR/settings.toml: not when started from that very
// file without overrides; InputError with overrides (it would replace it).
bool checkSettingsFileTarget(const std::vector<std::string>& overrides, const std::string& file, const std::string& dir);
// The job both pipelines run: the settings, the source with its grid, the output folder.
host::RunJob makeJob(const Settings& s, host::Source src, const Grid& grid, const std::string& dir,
                     const std::atomic<bool>* interrupt);
void writeSettingsFile(const ConfigSchema& schema, const std::string& dir);

}  // namespace pp5::app
