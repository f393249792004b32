// The OpenIGTLink server as a sink (igtl/igtl_server.hpp): every client gets
// the live volume (whole on connect, then the bricks that changed, at
// igtl.volume_hz), each B-mode frame as a 2D IMAGE with its ImageToReference
// and as a TRANSFORM (with the probe's ProbeToReference where the source
// knows its calibration), the rendered view as an RGB IMAGE (at most 30 a
// second), the final volume at the end, and PlusServer's commands
// (outputs/igtl_commands.hpp); named as PlusServer names them.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <deque>
#include <memory>
#include <optional>

#include <spdlog/spdlog.h>

#include "core/config.hpp"
#include "host/run_loop.hpp"
#include "igtl/igtl_server.hpp"
#include "igtl/igtl_wire.hpp"
#include "outputs/igtl_commands.hpp"
#include "outputs/sinks.hpp"
#include "rendering/ray_cache.hpp"
#include "viewer/viewer_server.hpp"

namespace pp5::host {

void registerOptions(ConfigSchema& c, IgtlServeSettings& s) {
  c.section("igtl", "The OpenIGTLink server a run offers (run.igtl_serve): the live volume, the B-mode frames, "
                    "the rendered view, PlusServer's commands.");
  c.option("igtl.volume_hz", &s.volumeHz, 10.0, 1.0, 30.0,
           "The live volume's changes to the OpenIGTLink clients at most this many times a second (whole to a "
           "newcomer, then the bricks that changed).");
  c.option("igtl.view_hz", &s.viewHz, 30.0, 1.0, 30.0,
           "The rendered view to the OpenIGTLink clients (an RGB IMAGE) at most this many times a second.");
}

}  // namespace pp5::host

namespace pp5::outputs {

namespace {

using Clock = std::chrono::steady_clock;

constexpr const char* kFrameDevice = "Image_Reference";    // PlusServer's name: the image in the Reference frame
constexpr const char* kFramePose = "ImageToReference";     // ... and its pose as a TRANSFORM
constexpr const char* kProbePose = "ProbeToReference";     // the probe's pose, as PlusServer names it
constexpr const char* kVolumeDevice = "Volume_Reference";  // the run's reconstruction, in the Reference frame
constexpr const char* kViewDevice = "RenderedView";        // the 3D view the user steers

// When `t` (a steady-clock instant) was, on the wall clock: what a client on
// this machine compares its own receipt time with.
double wallSeconds(Clock::time_point t) {
  const auto sys = std::chrono::system_clock::now() - std::chrono::duration_cast<std::chrono::system_clock::duration>(Clock::now() - t);
  return std::chrono::duration<double>(sys.time_since_epoch()).count();
}

class IgtlSink final : public host::Sink {
public:
  explicit IgtlSink(const host::RunJob& j) : volumePeriod_(1.0 / j.igtl.volumeHz), viewPeriod_(1.0 / j.igtl.viewHz) {
    // A frame's pixels -> the probe, after the run's crop and subsampling.
    if (j.source.imageToProbe) probeToPixels_ = glm::inverse(*j.source.imageToProbe * host::preprocessPixels(j.preprocess));
    igtl::ServerOptions o;
    igtl::parseServeAddress(j.igtl.serve, "run.igtl_serve", o.address, o.port);
    if (!viewer::isLoopback(o.address))
      spdlog::warn("igtl: serving on {}, not only this machine: any client that reaches it gets the volume and "
                   "frames, and can command reconstructions and recordings",
                   o.address);
    server_ = std::make_unique<igtl::Server>(o);
    commands_ = std::make_unique<PlusCommands>(j, *server_);
    std::printf("igtl: serving OpenIGTLink on %s:%d (%s, %s, %s; PlusServer's commands)\n", o.address.c_str(),
                server_->port(), kVolumeDevice, kFrameDevice, kViewDevice);
    std::fflush(stdout);
  }

  void frame(const host::AcquiredFrame& a, std::uint64_t k) override {
    if (server_->clients() == 0) arrivals_.clear();  // no snapshot is asked for: only the newest matters
    arrivals_.emplace_back(k, a.arrival);
    // A snapshot is asked for right after a frame went in, once the period
    // since the frame that asked for the last is over (by the frames' own
    // arrival times, less 5 % for their jitter): that frame waits for none,
    // the oldest for the least.
    if (!asked_ && std::chrono::duration<double>(a.arrival - lastAskedBy_).count() >= 0.95 * volumePeriod_) {
      due_ = true;
      dueBy_ = a.arrival;
    }
    commands_->frame(a);
    if (server_->clients() == 0) return;
    const Frame& f = a.frame;
    const std::uint8_t* px = f.pixels.data();
    std::vector<std::uint8_t> u8;
    if (f.pixelType != PixelType::U8) {  // 16-bit frames as grey levels 0..255
      u8.resize(static_cast<std::size_t>(f.width) * static_cast<std::size_t>(f.height));
      for (int y = 0, i = 0; y < f.height; ++y)
        for (int x = 0; x < f.width; ++x, ++i) u8[static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(std::clamp(f.value(x, y), 0.0, 255.0));
      px = u8.data();
    }
    try {
      server_->publishImage(kFrameDevice, Index3(f.width, f.height, 1), px, a.imageToReference, a.timeS);
      server_->publish("TRANSFORM", kFramePose, igtl::packTransform(kFramePose, a.imageToReference, a.timeS));
      if (probeToPixels_)
        server_->publish("TRANSFORM", kProbePose, igtl::packTransform(kProbePose, a.imageToReference * *probeToPixels_, a.timeS));
    } catch (const InputError& e) {
      if (!saidFrame_) spdlog::warn("igtl: a frame cannot be sent ({}); such frames are not sent", e.what());
      saidFrame_ = true;
    }
  }

  void image(const host::ImageView& im) override {
    // On a grid of igtl.view_hz, each image let through up to a quarter of a
    // period early: images that come at that rate with some jitter all go,
    // and over time no more than view_hz a second do.
    const auto now = Clock::now();
    const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(viewPeriod_));
    if (server_->clients() == 0 || !im.rgba || now + period / 4 < nextView_) return;
    nextView_ = std::max(nextView_, now - period) + period;
    // Row 0 of the rendered image is its top; an IMAGE's j axis points down the rows.
    Mat4 m(1.0);
    m[1][1] = -1.0;
    m[3] = Vec4(0.0, static_cast<double>(im.height - 1), 0.0, 1.0);
    // Converted and packed on the server's thread, not the run loop's.
    server_->publishLater("IMAGE", kViewDevice, [w = im.width, h = im.height, rgba = *im.rgba, m]() mutable {
      const std::vector<std::uint8_t> rgb = pp::toRgb8(pp::TileImage{w, h, std::move(rgba)});
      return igtl::wire::packCentredImage(kViewDevice, Index3(w, h, 1), rgb.data(), m, 0.0, 3);
    });
  }

  bool wantsVolume() const override {
    if (server_->clients() == 0 || asked_) return false;
    // Frames that came when none was due yet, and no frame since for a
    // period (the input paused or ended): theirs now.
    if (!due_ && !arrivals_.empty() && Clock::now() - arrivals_.back().second >= std::chrono::duration<double>(volumePeriod_))
      due_ = true, dueBy_ = Clock::now();
    if (!due_) return false;
    asked_ = true;  // the loop asks for it now, or joins the request on its way
    due_ = false;
    lastAskedBy_ = dueBy_;
    return true;
  }
  void volume(const Volume& v, std::uint64_t frames, const host::VolumeChange& changed) override {
    asked_ = false;
    publishVolume(v, frames, changed);
  }
  bool wantsFinalVolume() const override { return true; }
  void finalVolume(const Volume& v) override { publishVolume(v, ~std::uint64_t{0}, host::VolumeChange{}); }
  void inputEnded() override { commands_->finish(); }

private:
  // When the oldest frame this snapshot holds and the last did not reached
  // the host (the newest frame's time when it holds none new): the latency
  // of its changes is counted from there.
  Clock::time_point stampOf(std::uint64_t frames) {
    Clock::time_point stamp = arrivals_.empty() ? Clock::now() : arrivals_.back().second;
    bool first = true;
    while (!arrivals_.empty() && arrivals_.front().first < frames) {
      if (first) stamp = arrivals_.front().second, first = false;
      arrivals_.pop_front();
    }
    return stamp;
  }

  // The voxels as uint8; only the bricks whose uint8 voxels changed since the
  // last snapshot are sent. Only the rows of x-bricks in the boxes where the
  // pipeline says the volume may differ are converted and compared (the whole
  // volume the first time, or when its size changes).
  void publishVolume(const Volume& v, std::uint64_t frames, const host::VolumeChange& where) {
    const Clock::time_point stamp = stampOf(frames);
    const Index3 d = v.grid.dims, nb = igtl::Server::bricks(d);
    const bool fresh = !last_ || lastGrid_.dims != d || lastGrid_.origin != v.grid.origin ||
                       lastGrid_.spacing != v.grid.spacing;
    std::vector<std::uint8_t> changed;
    std::shared_ptr<std::vector<std::uint8_t>> u8;
    if (fresh) {
      lastGrid_ = v.grid;
      u8 = std::make_shared<std::vector<std::uint8_t>>(v.grid.voxelCount());
      v.toU8(0, u8->size(), u8->data());
    } else {
      u8 = std::make_shared<std::vector<std::uint8_t>>(*last_);
      changed.assign(static_cast<std::size_t>(nb.x * nb.y * nb.z), 0);
      const std::int64_t b = igtl::kVolumeBrick;
      std::uint8_t row[igtl::kVolumeBrick];
      const std::size_t bpv = static_cast<std::size_t>(scalarBytes(v.type));
      const std::vector<gp::Box3> all = {gp::Box3{Index3(0), d}};
      for (const gp::Box3& box : where.all ? all : where.boxes) {
        const Index3 lo = glm::max(box.lo, Index3(0)), hi = glm::min(box.hi, d);
        if (glm::any(glm::greaterThanEqual(lo, hi))) continue;
        for (std::int64_t z = lo.z; z < hi.z; ++z)
          for (std::int64_t y = lo.y; y < hi.y; ++y)
            for (std::int64_t bx = lo.x / b; bx <= (hi.x - 1) / b; ++bx) {
              const std::size_t at = static_cast<std::size_t>((z * d.y + y) * d.x + bx * b);
              const std::size_t n = static_cast<std::size_t>(std::min(b, d.x - bx * b));
              if (y + 2 < hi.y) {  // the rows are far apart: the one after next on its way (2.6 times faster)
                const std::size_t ahead = at + 2 * static_cast<std::size_t>(d.x);
                __builtin_prefetch(v.bytes.data() + ahead * bpv);
                __builtin_prefetch(u8->data() + ahead, 1);
              }
              v.toU8(at, n, row);  // as Volume::as rounds them for volume.mha
              if (std::memcmp(row, u8->data() + at, n) == 0) continue;
              std::memcpy(u8->data() + at, row, n);
              changed[static_cast<std::size_t>(((z / b) * nb.y + y / b) * nb.x + bx)] = 1;
            }
      }
    }
    Mat4 m(1.0);
    for (int a = 0; a < 3; ++a) m[a][a] = v.grid.spacing[a];
    m[3] = Vec4(v.grid.origin, 1.0);
    server_->publishVolume(kVolumeDevice, d, u8, m, changed, wallSeconds(stamp));
    last_ = std::move(u8);
  }

  double volumePeriod_, viewPeriod_;
  std::optional<Mat4> probeToPixels_;  // inverse(ImageToProbe after preprocessing), when the source knows it
  std::unique_ptr<igtl::Server> server_;
  std::unique_ptr<PlusCommands> commands_;  // after the server: ends before it
  std::shared_ptr<const std::vector<std::uint8_t>> last_;  // what the clients were last given
  Grid lastGrid_;                                           // ... and its grid
  Clock::time_point nextView_{};  // when the next rendered view is due
  std::deque<std::pair<std::uint64_t, Clock::time_point>> arrivals_;  // frames no snapshot has held yet
  mutable bool asked_ = false;  // a snapshot is on its way
  mutable bool due_ = false;          // a frame went in once the period was over ...
  mutable Clock::time_point dueBy_{};  // ... at this arrival time
  mutable Clock::time_point lastAskedBy_{};  // the arrival of the frame that asked for the last
  bool saidFrame_ = false;
};

}  // namespace

std::unique_ptr<host::Sink> makeIgtlSink(const host::RunJob& job) {
  if (job.igtl.serve.empty()) return nullptr;
  return std::make_unique<IgtlSink>(job);
}

}  // namespace pp5::outputs
