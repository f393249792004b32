#include "app/source_settings.hpp"

#include <memory>
#include <mutex>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "reconstruction/recon_run.hpp"
#include "sim/sweep_cache.hpp"
#include "core/error.hpp"
#include "formats/plus_config.hpp"
#include "formats/recording_journal.hpp"
#include "host/sources.hpp"
#include "sim/simulate.hpp"

namespace pp5::app {

namespace {

// What a live source needs from the configuration: the calibration chain and a
// fixed grid (the extent of frames not yet acquired cannot be fitted).
PlusConfig liveConfig(const Settings& s, const std::string& what) {
  if (s.run.plusConfig.empty())
    throw InputError(fmt::format("run.source = \"{}\" needs run.plus_config (the PLUS device-set XML whose chain "
                                 "places each frame)", what));
  if (s.grid.autoExtent)
    throw InputError(fmt::format("run.source = \"{}\" is live: set grid.auto_extent = false and give grid.origin, "
                                 "grid.spacing and grid.dims", what));
  return readPlusConfig(s.run.plusConfig);
}

host::LiveSetup liveSetup(const Settings& s, const std::string& what) {
  host::LiveSetup l;
  l.config = liveConfig(s, what);
  l.grid = s.grid.fixedGrid();
  l.recordPath = s.run.record;
  return l;
}

}  // namespace

host::Source makeSource(const Settings& s) {
  // A recording that could not start is found before any frame is taken.
  if (!s.run.record.empty()) checkRecordingTarget(s.run.record);
  // The probe's calibration, where the source has one.
  auto withProbe = [](host::Source src, const PlusConfig& cfg) {
    src.imageToProbe = cfg.coordinates.get("Image", "Probe");
    return src;
  };
  if (s.run.source == SourceKind::Board) {
    const host::LiveSetup live = liveSetup(s, "board");
    return withProbe(host::boardSource(driverOptions(s), armCalibration(s), s.board.transform, live), live.config);
  }
  if (s.run.source == SourceKind::Igtl) {
    igtl::ClientOptions opt;
    opt.endpoint = igtl::parseIgtlUrl(s.run.igtlUrl);
    opt.reconnect = s.run.igtlReconnectS > 0.0;
    opt.reconnectTimeoutS = s.run.igtlReconnectS;
    const host::LiveSetup live = liveSetup(s, "igtl");
    return withProbe(host::igtlSource(opt, live), live.config);
  }
  if (s.run.source == SourceKind::Sequence) {
    if (s.run.sequence.empty() || s.run.plusConfig.empty())
      throw InputError("run.source = \"sequence\" needs run.sequence and run.plus_config");
    auto seq = std::make_shared<PosedSequence>(openPosedSequence(s.run.sequence, s.run.plusConfig));
    const Grid grid = commandGrid(*seq, s.recon, &s.grid, s.grid.spacing);
    return host::recorded(withProbe(host::sequenceSource(seq, grid), seq->config), s.run.record);
  }
  auto sim = std::make_shared<sim::SweepSimulator>(s.sim);
  if (s.run.simulateLive) {
    host::Source src = host::simulatorSource(sim, sweepGrid(s, *sim), s.sim.threads);
    src.imageToProbe = sim->imageToProbe();
    return host::recorded(src, s.run.record);
  }
  // The sweep from the cache, on the live simulator's grid. Filling the cache
  // takes seconds the first time, so it is the source's prepare step: the
  // host runs it once the viewer's URL is out.
  // Where no cache folder can be made (no HOME, a read-only one), the run
  // simulates live instead and says so.
  struct Cached {
    Settings s;
    Grid grid;
    std::shared_ptr<sim::SweepSimulator> sim;
    std::once_flag once;
    host::Source inner;
    void ready() {
      std::call_once(once, [this] {
        sim::SimulatedSweep sweep;
        try {
          sweep = sim::cachedSweep(s.sim, sweepGridOf(s), s.run.sweepCache);
        } catch (const InputError& e) {
          spdlog::warn("run: {}; simulating every frame live instead (run.simulate_live)", e.what());
          inner = host::simulatorSource(sim, grid, s.sim.threads);
          return;
        }
        inner = host::sequenceSource(
            std::make_shared<PosedSequence>(openPosedSequence(sweep.sequencePath, sweep.configPath)), grid);
      });
    }
  };
  const Grid grid = sweepGrid(s, *sim);
  auto cached = std::make_shared<Cached>();
  cached->s = s;
  cached->grid = grid;
  cached->sim = sim;
  host::Source src = host::simulatorSource(sim, grid, s.sim.threads);  // its description, frames and grid
  src.description += " (simulated once, streamed from run.sweep_cache)";
  src.imageToProbe = sim->imageToProbe();
  src.prepare = [cached] { cached->ready(); };
  src.run = [cached](const host::FrameSink& sink) {
    cached->ready();
    cached->inner.run(sink);
  };
  return host::recorded(src, s.run.record);
}

board::DriverOptions driverOptions(const Settings& s) {
  board::DriverOptions o;
  o.vendorId = static_cast<std::uint16_t>(s.board.vendorId);
  o.productId = static_cast<std::uint16_t>(s.board.productId);
  o.transferBytes = s.board.transferKiB * 1024;
  o.transfers = s.board.transfers;
  o.queueFrames = static_cast<std::size_t>(s.board.queueFrames);
  o.dropOldest = s.board.drop == host::DropPolicy::Oldest;
  o.frameRate = s.board.frameRate;
  o.window[0] = s.board.windowOrigin.x;
  o.window[1] = s.board.windowOrigin.y;
  o.window[2] = s.board.windowSize.x;
  o.window[3] = s.board.windowSize.y;
  o.openTimeoutS = s.board.openTimeoutS;
  o.transferTimeoutS = s.board.transferTimeoutS;
  o.waitForReconnect = s.board.onUnplug == OnUnplug::Wait;
  o.reconnectTimeoutS = s.board.reconnectTimeoutS;
  o.limits.maxPayloadBytes = static_cast<std::uint32_t>(s.board.maxFrameBytes);
  return o;
}

board::ArmCalibration armCalibration(const Settings& s) {
  board::ArmCalibration c = board::ArmCalibration::linear(sim::armAdc(s.sim.arm), s.sim.arm.referenceToTrackerMm,
                                                                    s.board.armProbeZMm);
  const std::vector<std::string>* rows[3] = {&s.board.armXTable, &s.board.armYTable, &s.board.armThetaTable};
  const char* keys[3] = {"board.arm_x_table", "board.arm_y_table", "board.arm_theta_table"};
  for (int ch = 0; ch < 3; ++ch)
    if (!rows[ch]->empty()) c.table[static_cast<std::size_t>(ch)] = board::parseArmTable(*rows[ch], ch, keys[ch]);
  c.validate("[board] arm calibration");
  return c;
}

std::vector<std::string> sourceOverrides(const std::string& source) {
  if (source == "board" || source == "simulator" || source == "sequence")
    return {fmt::format("run.source=\"{}\"", source)};
  if (source.rfind("igtl://", 0) == 0) {
    igtl::parseIgtlUrl(source);  // refuse a bad URL here, naming it
    return {"run.source=\"igtl\"", fmt::format("run.igtl_url=\"{}\"", source)};
  }
  throw InputError(fmt::format("--source {}: expected board, igtl://HOST:PORT, sequence or simulator", source));
}

}  // namespace pp5::app
