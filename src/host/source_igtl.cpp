#include <atomic>
#include <memory>

#include <fmt/format.h>

#include "host/recorder.hpp"
#include "host/sources.hpp"

namespace pp5::host {

Source igtlSource(const igtl::ClientOptions& opt, const LiveSetup& live) {
  struct State {
    std::unique_ptr<igtl::Client> client;
    std::atomic<bool> stop{false};
    Placer placer;
  };
  auto st = std::make_shared<State>();
  st->placer.cfg = live.config;
  st->client = std::make_unique<igtl::Client>(opt);
  const std::string record = live.recordPath;
  Source src;
  src.live = true;
  src.grid = live.grid;
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
        "\"skipped\": {}, \"rejected\": {}, \"disconnects\": {}, \"reconnects\": {}, \"bytes\": {}, \"unplaced\": {}}}",
        c.images, c.transforms, c.paired, c.imagesWithoutPose, c.skipped, c.rejected, c.disconnects, c.reconnects, c.bytes,
        st->placer.unplaced.load());
  };
  return src;
}

}  // namespace pp5::host
