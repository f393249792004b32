#include "app/sources.hpp"

#include <atomic>
#include <memory>
#include <mutex>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "app/recon_run.hpp"
#include "core/error.hpp"
#include "core/plus_config.hpp"
#include "core/sequence_io.hpp"
#include "igtl/igtl_client.hpp"
#include "interface_board/board_frames.hpp"
#include "sim/simulate.hpp"

namespace pp5::app {

using host::FrameSink;
using host::Source;

namespace {

// Writes every frame a source produces to run.record, closing the file when
// the source ends (however it ends), so that nothing acquired is lost.
class Recorder {
public:
  explicit Recorder(const std::string& path) : path_(path) {}
  ~Recorder() {
    try {
      close();
    } catch (const std::exception& e) {
      spdlog::error("run.record: {}: {}", path_, e.what());
    }
  }
  void write(const Frame& f) {
    if (path_.empty()) return;
    if (!w_) w_ = SequenceWriter::create(path_);
    w_->write(f);
    ++frames_;
  }
  void close() {
    if (!w_) return;
    auto w = std::move(w_);
    w->close();
    spdlog::info("run.record: {} frames written to {}", frames_, path_);
  }

private:
  std::string path_;
  std::unique_ptr<SequenceWriter> w_;
  std::uint64_t frames_ = 0;
};

Source simulatorSource(const Settings& s) {
  auto sim = std::make_shared<sim::SweepSimulator>(s.sim);
  Source src;
  src.frames = sim->frameCount();
  if (src.frames == 0)
    throw InputError("sim.sweep: the sweep captured no frames; lengthen it or lower sim.sweep.capture_interval_mm");
  src.description = fmt::format("simulated {} sweep over the {} phantom, {} probe, {} frames", s.sim.sweep.kind,
                                s.sim.phantom, sim->probe().name, src.frames);
  src.grid = sweepGrid(s, *sim);
  const int threads = s.sim.threads;
  src.run = [sim, threads](const FrameSink& sink) {
    sim->run(threads, [&](Frame&& f) { sink(f, sim->imageToReference(f.index), f.timestamp); });
  };
  return src;
}

Source sequenceSource(const Settings& s) {
  if (s.run.sequence.empty() || s.run.plusConfig.empty())
    throw InputError("run.source = \"sequence\" needs run.sequence and run.plus_config");
  auto seq = std::make_shared<PosedSequence>(openPosedSequence(s.run.sequence, s.run.plusConfig));
  Source src;
  src.frames = seq->reader->info().frameCount;
  src.description = fmt::format("{} ({} frames of {}x{})", s.run.sequence, src.frames, seq->reader->info().width,
                                seq->reader->info().height);
  src.grid = s.grid.autoExtent ? chooseGrid(*seq, s.recon, s.grid.spacing, s.grid.marginMm, false) : s.grid.fixedGrid();
  src.run = [seq](const FrameSink& sink) {
    Frame f;
    for (std::uint64_t i = 0; seq->reader->next(f); ++i)
      if (seq->poses[i]) sink(f, *seq->poses[i], f.timestamp);
  };
  return src;
}


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

// Places a live frame: ImageToReference through the configuration's chain, or
// nullopt (counted) when the frame cannot be placed.
struct Placer {
  PlusConfig cfg;
  std::atomic<std::uint64_t> unplaced{0};
  std::optional<Mat4> place(const Frame& f) {
    auto pose = f.imageValid ? imageToReference(cfg, f) : std::nullopt;
    if (pose && !isFinite(*pose)) pose.reset();
    if (!pose && unplaced++ == 0)
      spdlog::warn("live frame {} cannot be placed (invalid status or no ImageToReference chain); such frames are "
                   "skipped and counted",
                   f.index);
    return pose;
  }
};

Source boardSource(const Settings& s) {
  struct State {
    std::mutex m;
    std::unique_ptr<board::BoardDriver> driver;
    board::DriverStats last;
    std::string endReason;
    std::atomic<bool> stop{false};
    Placer placer;
  };
  auto st = std::make_shared<State>();
  st->placer.cfg = liveConfig(s, "board");
  const board::DriverOptions opt = driverOptions(s);
  auto arm = std::make_shared<board::ArmCalibration>(armCalibration(s));
  const std::string transform = s.board.transform, record = s.run.record;
  Source src;
  src.live = true;
  src.grid = s.grid.fixedGrid();
  src.description = fmt::format("interface board {:04x}:{:04x}", s.board.vendorId, s.board.productId);
  src.run = [st, opt, arm, transform, record](const FrameSink& sink) {
    Recorder rec(record);
    {
      auto d = std::make_unique<board::BoardDriver>(opt);
      std::lock_guard lk(st->m);
      st->driver = std::move(d);
    }
    board::BoardDriver& drv = *st->driver;
    board::WireFrame w;
    bool ended = false;
    while (!st->stop) {
      if (!drv.next(w, 0.1, ended)) {
        if (ended) break;
        continue;
      }
      Frame f = board::fromWireFrame(std::move(w), transform, arm.get());
      rec.write(f);
      if (const auto pose = st->placer.place(f)) sink(f, *pose, f.timestamp);
    }
    std::lock_guard lk(st->m);
    st->endReason = ended ? drv.endReason() : "stopped";
    st->last = drv.stats();
    st->driver.reset();  // stops the board
  };
  src.interrupt = [st] { st->stop = true; };
  src.statsJson = [st] {
    std::lock_guard lk(st->m);
    const board::DriverStats d = st->driver ? st->driver->stats() : st->last;
    return fmt::format("{{\"kind\": \"board\", \"end\": \"{}\", {}, \"unplaced\": {}}}", st->endReason,
                       board::jsonFields(d), st->placer.unplaced.load());
  };
  return src;
}

Source igtlSource(const Settings& s) {
  struct State {
    std::unique_ptr<igtl::Client> client;
    std::atomic<bool> stop{false};
    Placer placer;
  };
  auto st = std::make_shared<State>();
  st->placer.cfg = liveConfig(s, "igtl");
  igtl::ClientOptions opt;
  opt.endpoint = igtl::parseIgtlUrl(s.run.igtlUrl);
  opt.reconnect = s.run.igtlReconnectS > 0.0;
  opt.reconnectTimeoutS = s.run.igtlReconnectS;
  st->client = std::make_unique<igtl::Client>(opt);
  const std::string record = s.run.record;
  Source src;
  src.live = true;
  src.grid = s.grid.fixedGrid();
  src.description = fmt::format("OpenIGTLink server {}", igtl::toString(opt.endpoint));
  src.run = [st, record](const FrameSink& sink) {
    Recorder rec(record);
    st->client->run(
        [&](Frame&& f) {
          rec.write(f);
          if (const auto pose = st->placer.place(f)) sink(f, *pose, f.timestamp);
        },
        st->stop);
  };
  src.interrupt = [st] { st->stop = true; };
  src.statsJson = [st] {
    const igtl::ClientStats c = st->client->stats();
    return fmt::format(
        "{{\"kind\": \"igtl\", \"images\": {}, \"transforms\": {}, \"paired\": {}, \"images_without_pose\": {}, "
        "\"skipped\": {}, \"disconnects\": {}, \"reconnects\": {}, \"bytes\": {}, \"unplaced\": {}}}",
        c.images, c.transforms, c.paired, c.imagesWithoutPose, c.skipped, c.disconnects, c.reconnects, c.bytes,
        st->placer.unplaced.load());
  };
  return src;
}

// Records a file source's frames too, when asked.
Source recorded(Source src, const std::string& path) {
  if (path.empty()) return src;
  auto inner = src.run;
  src.run = [inner, path](const FrameSink& sink) {
    Recorder rec(path);
    inner([&](const Frame& f, const Mat4& pose, double t) {
      rec.write(f);
      sink(f, pose, t);
    });
  };
  return src;
}

}  // namespace

Source makeSource(const Settings& s) {
  if (s.run.source == "board") return boardSource(s);
  if (s.run.source == "igtl") return igtlSource(s);
  return recorded(s.run.source == "sequence" ? sequenceSource(s) : simulatorSource(s), s.run.record);
}

board::DriverOptions driverOptions(const Settings& s) {
  board::DriverOptions o;
  o.vendorId = static_cast<std::uint16_t>(s.board.vendorId);
  o.productId = static_cast<std::uint16_t>(s.board.productId);
  o.transferBytes = s.board.transferKiB * 1024;
  o.transfers = s.board.transfers;
  o.queueFrames = static_cast<std::size_t>(s.board.queueFrames);
  o.dropOldest = s.board.drop == "oldest";
  o.frameRate = s.board.frameRate;
  o.window[0] = s.board.windowOrigin.x;
  o.window[1] = s.board.windowOrigin.y;
  o.window[2] = s.board.windowSize.x;
  o.window[3] = s.board.windowSize.y;
  o.openTimeoutS = s.board.openTimeoutS;
  o.transferTimeoutS = s.board.transferTimeoutS;
  o.waitForReconnect = s.board.onUnplug == "wait";
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
