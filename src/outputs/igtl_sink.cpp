// The OpenIGTLink server as a sink (igtl/igtl_server.hpp): every client gets
// the live volume as a 3D IMAGE at igtl.volume_hz (whole on connect), each
// B-mode frame as a 2D IMAGE with its ImageToReference, and the final volume
// at the end, named as PlusServer names its images (Image_Reference).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>

#include <spdlog/spdlog.h>

#include "core/config.hpp"
#include "host/run_loop.hpp"
#include "igtl/igtl_server.hpp"
#include "outputs/sinks.hpp"
#include "viewer/viewer_server.hpp"

namespace pp5::host {

void registerOptions(ConfigSchema& c, IgtlServeSettings& s) {
  c.section("igtl", "The OpenIGTLink server a run offers (run.igtl_serve): the live volume, the B-mode frames.");
  c.option("igtl.volume_hz", &s.volumeHz, 10.0, 1.0, 30.0,
           "The live volume to the OpenIGTLink clients at most this many times a second (whole each time).");
}

}  // namespace pp5::host

namespace pp5::outputs {

namespace {

using Clock = std::chrono::steady_clock;

constexpr const char* kFrameDevice = "Image_Reference";    // PlusServer's name: the image in the Reference frame
constexpr const char* kVolumeDevice = "Volume_Reference";  // the reconstruction, in the Reference frame

class IgtlSink final : public host::Sink {
public:
  explicit IgtlSink(const host::RunJob& j) : period_(1.0 / j.igtl.volumeHz) {
    igtl::ServerOptions o;
    igtl::parseServeAddress(j.igtl.serve, "run.igtl_serve", o.address, o.port);
    if (!viewer::isLoopback(o.address))
      spdlog::warn("igtl: serving on {}, not only this machine: any client that reaches it gets the volume and "
                   "frames",
                   o.address);
    server_ = std::make_unique<igtl::Server>(o);
    std::printf("igtl: serving OpenIGTLink on %s:%d (%s, %s)\n", o.address.c_str(), server_->port(), kVolumeDevice,
                kFrameDevice);
    std::fflush(stdout);
  }

  void start(const host::RunStart& r) override { grid_ = r.grid; }

  void frame(const host::AcquiredFrame& a, std::uint64_t) override {
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
    } catch (const InputError& e) {
      if (!saidFrame_) spdlog::warn("igtl: a frame cannot be sent ({}); such frames are not sent", e.what());
      saidFrame_ = true;
    }
  }

  bool wantsVolume() const override {
    return server_->clients() > 0 && Clock::now() - lastVolume_ >= std::chrono::duration<double>(period_);
  }
  void volume(const Volume& v) override {
    lastVolume_ = Clock::now();
    publishVolume(v);
  }
  bool wantsFinalVolume() const override { return true; }
  void finalVolume(const Volume& v) override { publishVolume(v); }

private:
  void publishVolume(const Volume& v) {
    const Volume u8 = v.type == ScalarType::U8 ? v : v.as(ScalarType::U8);
    Mat4 m(1.0);
    for (int a = 0; a < 3; ++a) m[a][a] = v.grid.spacing[a];
    m[3] = Vec4(v.grid.origin, 1.0);
    server_->publishImage(kVolumeDevice, v.grid.dims, u8.bytes.data(), m, 0.0);
  }

  double period_;
  Grid grid_;
  std::unique_ptr<igtl::Server> server_;
  Clock::time_point lastVolume_{};
  bool saidFrame_ = false;
};

}  // namespace

std::unique_ptr<host::Sink> makeIgtlSink(const host::RunJob& job) {
  if (job.igtl.serve.empty()) return nullptr;
  return std::make_unique<IgtlSink>(job);
}

}  // namespace pp5::outputs
