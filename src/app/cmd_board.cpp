// `pp5echo board-emulator`: an emulated interface board on umockdev, serving
// a command run beside it; `pp5echo board-stats`: the driver alone, receiving
// frames and reporting its counters (and checking the frames against the file
// they came from).
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "app/commands.hpp"
#include "app/settings.hpp"
#include "app/source_settings.hpp"
#include "core/error.hpp"
#include "core/io_util.hpp"
#include "formats/sequence_io.hpp"
#include "interface_board/board_emulator.hpp"
#include "interface_board/board_frames.hpp"
#include "sim/simulate.hpp"

namespace pp5::app {

namespace {

struct EmulatorArgs {
  std::string config, sequence, pose = "matrix", transform = "ProbeToTracker", statsJson;
  std::vector<std::string> overrides, faults, command;
  std::uint64_t frames = 0;
  double fps = 30.0;
  int vid = 0, pid = 0;
  bool keepTimestamps = false;
};

// The frames the board will send: a sequence file's, or the [sim] sweep's.
std::vector<board::WireFrame> emulatorFrames(const EmulatorArgs& a) {
  const board::PoseKind kind = board::poseKindFromName(a.pose);
  std::vector<board::WireFrame> out;
  auto take = [&](const Frame& f) {
    if (a.frames && out.size() >= a.frames) return false;
    out.push_back(board::toWireFrame(f, kind, a.transform));
    return true;
  };
  if (!a.sequence.empty()) {
    auto r = SequenceReader::open(a.sequence);
    Frame f;
    while (r->next(f) && take(f)) {
    }
  } else {
    const Settings s = readSettings(a.config, a.overrides);
    sim::SweepSimulator sim(s.sim);
    spdlog::info("board emulator: simulating {} frames", sim.frameCount());
    bool more = true;
    sim.run(s.sim.threads, [&](Frame&& f) { more = more && take(f); });
  }
  if (out.empty()) throw InputError("board emulator: no frames to stream");
  return out;
}

int runEmulator(const EmulatorArgs& a) {
  board::EmulatorOptions opt;
  opt.vendorId = static_cast<std::uint16_t>(a.vid);
  opt.productId = static_cast<std::uint16_t>(a.pid);
  opt.fps = a.fps;
  opt.keepTimestamps = a.keepTimestamps;
  for (const auto& f : a.faults) opt.faults.push_back(board::parseFault(f));
  std::vector<board::WireFrame> frames = emulatorFrames(a);
  const std::size_t n = frames.size();
  board::BoardEmulator emu(std::move(frames), opt);
  spdlog::info("board emulator: {} frames at {} fps, {} fault(s); running: {}", n, a.fps, opt.faults.size(),
               fmt::join(a.command, " "));
  const int status = emu.runChild(a.command);
  const board::EmulatorStats st = emu.stats();
  const std::string json = fmt::format(
      "{{\"frames\": {}, \"frames_sent\": {}, \"bytes_sent\": {}, \"urbs\": {}, \"faults_injected\": {}, "
      "\"unplugs\": {}, \"reconnects\": {}, \"stalls_cleared\": {}, \"child_status\": {}}}\n",
      n, st.framesSent, st.bytesSent, st.urbsCompleted, st.faultsInjected, st.unplugs, st.reconnects,
      st.stallsCleared, status);
  std::fprintf(stderr, "board emulator: %s", json.c_str());
  if (!a.statsJson.empty()) {
    io::AtomicFile f(a.statsJson);
    f.write(json);
    f.commit();
  }
  return status;
}

struct StatsArgs {
  std::string config, expect, json;
  std::vector<std::string> overrides;
  std::uint64_t frames = 0;
  double seconds = 30.0;
};

// Receives from the board until `frames` frames, the end of the stream, or
// `seconds`; with `expect`, checks each frame's pixels and pose against the
// file's frame of the same sequence number.
int runStats(const StatsArgs& a) {
  const Settings s = readSettings(a.config, a.overrides);
  std::vector<Frame> expected;
  if (!a.expect.empty()) expected = readAllFrames(a.expect);
  const board::ArmCalibration arm = armCalibration(s);

  std::uint64_t received = 0, pixelMismatches = 0, poseMismatches = 0, unknown = 0;
  std::vector<bool> seen(expected.size(), false);
  double worstArmPoseMm = 0.0;
  board::DriverStats st;
  std::string end;
  {
    board::BoardDriver drv(driverOptions(s));
    const auto t0 = std::chrono::steady_clock::now();
    board::WireFrame w;
    bool ended = false;
    while ((!a.frames || received < a.frames) &&
           std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() < a.seconds) {
      if (!drv.next(w, 0.1, ended)) {
        if (ended) break;
        continue;
      }
      ++received;
      if (expected.empty()) continue;
      const std::uint32_t seq = w.sequence;
      const board::PoseKind kind = w.poseKind;
      const auto counts = w.armCounts;
      if (seq >= expected.size()) {
        ++unknown;
        continue;
      }
      const Frame& e = expected[seq];
      seen[seq] = true;
      Frame f = board::fromWireFrame(std::move(w), s.board.transform, &arm);
      if (f.pixels != e.pixels || f.width != e.width || f.height != e.height) ++pixelMismatches;
      const FrameTransform* got = f.findTransform(s.board.transform);
      const FrameTransform* want = e.findTransform(s.board.transform);
      if (kind == board::PoseKind::Matrix) {
        if (!got || !want || got->matrix != want->matrix) ++poseMismatches;
      } else if (kind == board::PoseKind::ArmCounts) {
        // The counts are exact; the file's pose was interpolated between A/D
        // readings, so the calibrated pose is compared within a tolerance.
        const std::string* field = e.findField("ArmCounts");
        if (!field || *field != fmt::format("{} {} {}", counts[0], counts[1], counts[2])) ++poseMismatches;
        if (got && want) worstArmPoseMm = std::max(worstArmPoseMm, glm::length(Vec3(got->matrix[3] - want->matrix[3])));
      }
    }
    st = drv.stats();
    end = ended ? drv.endReason() : "stopped";
  }
  std::vector<std::uint32_t> missing;
  for (std::size_t i = 0; i < seen.size(); ++i)
    if (!seen[i]) missing.push_back(static_cast<std::uint32_t>(i));
  const std::string json = fmt::format(
      "{{\"received\": {}, \"end\": \"{}\", {}, \"expected\": {}, \"pixel_mismatches\": {}, "
      "\"pose_mismatches\": {}, \"unknown_frames\": {}, \"arm_pose_worst_mm\": {:.4f}, \"missing\": [{}]}}\n",
      received, end, board::jsonFields(st), expected.size(), pixelMismatches, poseMismatches, unknown, worstArmPoseMm,
      fmt::join(missing, ", "));
  std::printf("%s", json.c_str());
  if (!a.json.empty()) {
    io::AtomicFile f(a.json);
    f.write(json);
    f.commit();
  }
  return 0;
}

}  // namespace

std::vector<std::string>& trailingCommand() {
  static std::vector<std::string> command;
  return command;
}

void addBoardCommands(CLI::App& app, int& exitCode) {
  auto e = std::make_shared<EmulatorArgs>();
  auto* emu = app.add_subcommand(
      "board-emulator",
      "Emulate the USB interface board on umockdev and run COMMAND (after --) so that its libusb sees the board");
  emu->add_option("--config", e->config, "TOML configuration for the simulated sweep (when no --sequence)");
  emu->add_option("--set", e->overrides, "Override an option of CONFIG: key=value (repeatable)");
  emu->add_option("--sequence", e->sequence, "Stream this PLUS sequence's frames (default: simulate the [sim] sweep)");
  emu->add_option("--frames", e->frames, "Stream at most this many frames (0 = all)");
  emu->add_option("--fps", e->fps, "Frames per second once the host starts the board (0 = as fast as it reads)")
      ->check(CLI::Range(0.0, 10000.0));
  emu->add_option("--pose", e->pose, "matrix (the --transform of each frame), arm (its ArmCounts field) or none")
      ->check(CLI::IsMember({"matrix", "arm", "none"}));
  emu->add_option("--transform", e->transform, "The per-frame transform sent as the matrix pose");
  emu->add_option("--fault", e->faults,
                  "Inject a fault: bad_crc@N, drop@N, short@N, stall@N, unplug@N (gone for good) or unplug@N:SECONDS "
                  "(comes back after SECONDS); N is the frame (repeatable)");
  emu->add_option("--vid", e->vid, "USB vendor id (default 0x1209)")->check(CLI::Range(0, 0xffff));
  emu->add_option("--pid", e->pid, "USB product id (default 0x0001)")->check(CLI::Range(0, 0xffff));
  emu->add_flag("--keep-timestamps", e->keepTimestamps,
                "Send the source's timestamps (default: the board's clock when it sends the frame)");
  emu->add_option("--stats-json", e->statsJson, "Write the emulator's counters here at the end");
  // Everything after `--` is the command, untouched (main() splits it off
  // before parsing, since the command has options of its own).
  emu->footer("Usage: pp5echo board-emulator [OPTIONS] -- COMMAND [ARGS...]");
  emu->callback([e, &exitCode] {
    e->command = trailingCommand();
    if (e->command.empty()) throw InputError("board-emulator: give the command to run after --");
    exitCode = runEmulator(*e);
  });

  auto a = std::make_shared<StatsArgs>();
  auto* st = app.add_subcommand("board-stats", "Receive frames from the interface board and report the driver's "
                                               "counters as JSON (frames/s, MB/s, CRC errors, resyncs, drops, latency)");
  st->add_option("CONFIG", a->config, "TOML configuration ([board])");
  st->add_option("--set", a->overrides, "Override an option: key=value (repeatable)");
  st->add_option("--frames", a->frames, "Stop after this many frames (0 = until the stream ends)");
  st->add_option("--seconds", a->seconds, "Stop after this long")->check(CLI::Range(0.0, 1e6));
  st->add_option("--expect", a->expect, "Check every frame against this PLUS sequence (pixels and pose)");
  st->add_option("--json", a->json, "Also write the JSON here");
  st->callback([a, &exitCode] { exitCode = runStats(*a); });
}

}  // namespace pp5::app
