#include <atomic>
#include <memory>
#include <mutex>

#include <fmt/format.h>

#include "host/recorder.hpp"
#include "host/sources.hpp"
#include "interface_board/board_frames.hpp"

namespace pp5::host {

Source boardSource(const board::DriverOptions& opt, const board::ArmCalibration& armCalibration,
                   const std::string& transform, const LiveSetup& live) {
  struct State {
    std::mutex m;
    std::unique_ptr<board::BoardDriver> driver;
    board::DriverStats last;
    std::string endReason;
    std::atomic<bool> stop{false};
    Placer placer;
  };
  auto st = std::make_shared<State>();
  st->placer.cfg = live.config;
  auto arm = std::make_shared<board::ArmCalibration>(armCalibration);
  const std::string record = live.recordPath;
  Source src;
  src.live = true;
  src.grid = live.grid;
  src.description = fmt::format("interface board {:04x}:{:04x}", opt.vendorId, opt.productId);
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

}  // namespace pp5::host
