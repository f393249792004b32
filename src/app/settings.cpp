#include "app/settings.hpp"

#include <filesystem>

#include "core/error.hpp"
#include "outputs/outputs.hpp"
#include "sim/simulate.hpp"

namespace pp5::app {

void registerAll(ConfigSchema& schema, Settings& s) {
  sim::registerOptions(schema, s.sim);

  gp::registerOptions(schema, s.grid);
  gp::registerOptions(schema, s.recon);
  registerOptions(schema, s.render);
  gp::registerOptions(schema, s.shading);
  registerOptions(schema, s.tf);
  pp::registerOptions(schema, s.cache);

  schema.section("board", "The USB interface board (`run.source = \"board\"`); see docs/protocol.md.");
  schema.option("board.vendor_id", &s.board.vendorId, 0x1209, 0, 0xffff, "The board's USB vendor id.");
  schema.option("board.product_id", &s.board.productId, 0x0001, 0, 0xffff, "The board's USB product id.");
  schema.option("board.transfer_kib", &s.board.transferKiB, 256, 1, 65536, "Size of each bulk IN transfer, KiB.");
  schema.option("board.transfers", &s.board.transfers, 8, 1, 256, "Bulk transfers kept in flight (the ring).");
  schema.option("board.queue_frames", &s.board.queueFrames, 32, 1, 100000,
                "Decoded frames the driver holds for the acquisition thread; beyond that it drops (`board.drop`).");
  enumOption(schema, "board.drop", &s.board.drop, host::DropPolicy::Oldest,
                "The driver's queue is full: drop its oldest frame, or the new one. Drops are counted.");
  schema.option("board.frame_rate", &s.board.frameRate, 0.0, 0.0, 655.0,
                "Ask the board for this frame rate (SetFrameRate); 0 = leave the board's own rate.");
  schema.option("board.window_origin", &s.board.windowOrigin, {0, 0}, 0, 65535,
                "Capture window's corner in pixels (SetWindow), with `board.window_size`.");
  schema.option("board.window_size", &s.board.windowSize, {0, 0}, 0, 65535,
                "Capture window's width and height; 0 0 = the whole frame (no SetWindow).");
  schema.option("board.open_timeout_s", &s.board.openTimeoutS, 5.0, 0.0, 3600.0,
                "Wait this long for the board to appear when the run starts.");
  schema.option("board.transfer_timeout_s", &s.board.transferTimeoutS, 2.0, 0.05, 3600.0,
                "A bulk transfer with no data for this long counts as a timeout (and is resubmitted).");
  enumOption(schema, "board.on_unplug", &s.board.onUnplug, OnUnplug::End,
                "The board is unplugged: end the stream cleanly, or wait `board.reconnect_timeout_s` for it to come "
                "back (at any address) and go on.");
  schema.option("board.reconnect_timeout_s", &s.board.reconnectTimeoutS, 10.0, 0.0, 86400.0,
                "How long `board.on_unplug = \"wait\"` waits for the board.");
  schema.option("board.transform", &s.board.transform, "ProbeToTracker",
                "The per-frame transform the board's pose becomes (a 6-DOF matrix as is, arm counts through the "
                "calibration); `run.plus_config` places it.");
  schema.option("board.arm_x_table", &s.board.armXTable, {},
                "Arm calibration, x channel: rows \"COUNT MM\", counts strictly increasing, linear between rows "
                "and beyond the ends. Empty: the simulator's linear converter ([sim.arm]).");
  schema.option("board.arm_y_table", &s.board.armYTable, {}, "Arm calibration, y channel: rows \"COUNT MM\".");
  schema.option("board.arm_theta_table", &s.board.armThetaTable, {},
                "Arm calibration, theta channel: rows \"COUNT DEGREES\".");
  schema.option("board.arm_probe_z_mm", &s.board.armProbeZMm, 0.0, -1e6, 1e6,
                "Height of the probe mount in the arm's (Tracker) frame, mm.");
  schema.option("board.max_frame_bytes", &s.board.maxFrameBytes, std::uint64_t{16u << 20}, std::uint64_t{1024},
                std::uint64_t{1u << 30}, "Largest frame payload believed; a header claiming more is rejected.");

  schema.section("run", "`pp5echo run`: the source it streams and the outputs it writes.");
  enumOption(schema, "run.source", &s.run.source, SourceKind::Simulator,
                "`simulator`: the [sim] sweep (simulated once into a cache and streamed from there, unless "
                "`run.simulate_live`); `sequence`: a PLUS sequence file "
                "(`run.sequence`, with `run.plus_config` for the calibration); `board`: the USB interface board "
                "([board]); `igtl`: an OpenIGTLink server (`run.igtl_url`). The live sources need "
                "`run.plus_config` for the calibration chain and a fixed grid (`grid.auto_extent = false`).");
  schema.option("run.igtl_url", &s.run.igtlUrl, "igtl://127.0.0.1:18944",
                "OpenIGTLink server for `run.source = \"igtl\"`, as igtl://HOST:PORT.");
  schema.option("run.igtl_reconnect_s", &s.run.igtlReconnectS, 10.0, 0.0, 86400.0,
                "The OpenIGTLink server went away: try to reconnect for this long, then end the stream (keeping "
                "what arrived); 0 ends it at once.");
  schema.option("run.igtl_serve", &s.igtl.serve, "",
                "Serve the run over OpenIGTLink on [ADDR:]PORT (127.0.0.1 unless an address is given; `run "
                "--igtl-serve`): every client (3D Slicer, PlusServer's clients) gets the live volume as IMAGE "
                "Volume_Reference at igtl.volume_hz and each B-mode frame as IMAGE Image_Reference, and answers to "
                "GET_IMAGE, GET_STATUS and GET_CAPABIL. \"\" = none.");
  schema.option("run.record", &s.run.record, "",
                "Write every acquired frame, as it arrives and before any drop, to this PLUS sequence file "
                "(`pp5echo record` sets it to OUT/recording.mha). Each frame also goes to FILE.journal until the "
                "file is complete, so a run killed at any moment keeps every frame: `pp5echo restore FILE.journal`.");
  schema.option("run.sequence", &s.run.sequence, "", "PLUS sequence file for `run.source = \"sequence\"`.");
  schema.option("run.plus_config", &s.run.plusConfig, "",
                "PLUS device-set XML giving the sequence's ImageToReference chain.");
  schema.option("run.simulate_live", &s.run.simulateLive, false,
                "`run.source = \"simulator\"`: simulate every frame on the host as it streams. Off (the default), "
                "the sweep is simulated once into `run.sweep_cache`, keyed by every [sim] setting but sim.threads "
                "and by the program, and streamed from there like a recording, so the host's core is free for the "
                "pipeline.");
  schema.option("run.sweep_cache", &s.run.sweepCache, "",
                "Folder of the simulated sweeps (each phantom's 4 most recently used are kept, and any used in "
                "the last hour); empty: $XDG_CACHE_HOME/pp5echo/sweeps, else ~/.cache/pp5echo/sweeps.");
  schema.option("run.buildup_every", &s.run.buildupEvery, 1, 1, 100000,
                "Every n-th frame's image goes into the build-up animation (`buildup.gif`).");
  schema.option("run.buildup_fps", &s.run.buildupFps, 15.0, 0.5, 100.0, "Frame rate of `buildup.gif`.");
  schema.option("run.orbit_frames", &s.run.orbitFrames, 36, 0, 3600,
                "Frames of the rotating movie loop of the final volume (`orbit.gif`, one turn about +z); 0 = none.");
  schema.option("run.orbit_fps", &s.run.orbitFps, 12.0, 0.5, 100.0, "Frame rate of `orbit.gif`.");
  schema.option("run.mpr", &s.run.mpr, true,
                "Write three orthogonal slices through the final volume's centre (`mpr_axial.png`, ...).");
  schema.option("run.mpr_size", &s.run.mprLook.longSide, 512, 8, 8192,
                "Pixels on the longer side of each written slice (trilinear; the other side keeps the proportions).");
  schema.option("run.mpr_window", &s.run.mprLook.window, 255.0, 1.0, 65535.0,
                "Grey levels the written slices map from black to white.");
  schema.option("run.mpr_level", &s.run.mprLook.level, 127.5, -65535.0, 65535.0,
                "The grey level at the middle of the written slices' window.");
  schema.option("run.volume", &s.run.volume, true, "Write the final reconstructed volume (`volume.mha`, 8 bit).");
  schema.option("run.script", &s.run.script, {},
                "Control changes by frame (serial and distributed runs alike): each entry is \"AFTER_FRAME key = value; key = value\" (the change follows the first frame sent whose source index is at least AFTER_FRAME), "
                "with keys among render.azimuth_deg, elevation_deg, distance, projection, fov_deg, compositing (the "
                "first is live), render.shading.* and render.tf.*; e.g. \"40 render.azimuth_deg = 0\".");
  schema.option("run.crop_origin", &s.run.cropOrigin, {0, 0}, 0, 100000,
                "Host preprocessing: the first column and row of the crop, pixels.");
  schema.option("run.crop_size", &s.run.cropSize, {0, 0}, 0, 100000,
                "Host preprocessing: crop each frame to this width and height, pixels; 0 0 = no crop.");
  schema.option("run.subsample", &s.run.subsample, 1, 1, 64,
                "Host preprocessing: after the crop, keep the mean of each n x n block of pixels.");
  schema.option("run.pace_fps", &s.run.paceFps, 0.0, 0.0, 10000.0,
                "Deliver the source's frames at this rate, as a live scanner would (0 = as fast as the pipeline "
                "takes them); a paced source that falls behind drops frames (`run.drop`). The same under mpirun "
                "and in one process (`--serial`, or `run` without mpirun).");
  schema.option("run.capture_interval_mm", &s.run.captureIntervalMm, 0.0, 0.0, 100.0,
                "Constant-interval capture on the host, for every source: take a frame only once some corner of "
                "the image has moved this far (mm) from the last frame taken, as the 1990 system digitised every "
                "2, 3 or 5 mm; 0 takes every frame. Counted in summary.json (`frames_left_out_by_interval`).");
  schema.option("run.queue_frames", &s.run.queueFrames, 8, 1, 100000,
                "Frames the acquisition thread may queue ahead of the pipeline.");
  enumOption(schema, "run.drop", &s.run.drop, host::DropPolicy::Oldest,
                "A live or paced (`run.pace_fps`) source's queue is full: drop the oldest queued frame, or the new one. Drops are counted and "
                "printed.");

  parallel::registerOptions(schema, s.parallel);
  host::registerOptions(schema, s.view);
  host::registerOptions(schema, s.igtl);

  schema.section("output", "Where results are written.");
  schema.option("output.dir", &s.output.dir, "out/doll", "Output folder, unless the command line gives `-o`.");
  schema.option("output.preview_frames", &s.output.previewFrames, 4, 0, 1000,
                "How many input frames `simulate` also writes as PNG, evenly spread over the sweep.");
}

sim::SweepGrid sweepGridOf(const Settings& s) {
  return [grid = s.grid](const sim::SweepSimulator& sim) {
    if (!grid.autoExtent) return grid.fixedGrid();
    std::vector<Mat4> poses;
    for (std::size_t i = 0; i < sim.frameCount(); ++i) poses.push_back(sim.imageToReference(i));
    return sim::fitGrid(poses, sim.probe().width, sim.probe().height, grid.spacing, grid.marginMm);
  };
}

Grid sweepGrid(const Settings& s, const sim::SweepSimulator& sim) { return sweepGridOf(s)(sim); }

void makeOutputDir(const std::string& dir) { host::createOutputFolder(dir); }

void loadSettings(ConfigSchema& schema, const std::string& file, const std::vector<std::string>& overrides) {
  schema.applyDefaults();
  if (!file.empty()) {
    if (!std::filesystem::exists(file)) throw InputError(file + ": configuration file not found");
    schema.loadFile(file);
  }
  for (const auto& o : overrides) schema.set(o);
}

Settings readSettings(const std::string& file, const std::vector<std::string>& overrides) {
  Settings s;
  ConfigSchema schema;
  registerAll(schema, s);
  loadSettings(schema, file, overrides);
  return s;  // the schema points into `s`, so it goes now; the values stay
}

}  // namespace pp5::app
