// The run's images as files: the build-up animation, the final image of each
// composition mode and the rotating loop.
#include <filesystem>
#include <memory>
#include <optional>

#include "formats/image_io.hpp"
#include "core/enum_names.hpp"
#include "host/run_loop.hpp"
#include "rendering/tile_caches.hpp"

namespace pp5::outputs {

namespace {

namespace fs = std::filesystem;

std::vector<std::uint8_t> rgb8(const host::ImageView& im) {
  return pp::toRgb8(pp::TileImage{im.width, im.height, *im.rgba});
}

// floor(a / b) for b > 0, so that frame -1 (none yet) counts below frame 0.
std::int64_t floorDiv(std::int64_t a, std::int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

// An animation a sink writes frame by frame, and names once it is closed.
class Animation {
public:
  Animation(std::string name, double fps) : name_(std::move(name)), fps_(fps) {}
  void open(const std::string& dir, int width, int height) {
    gif_.emplace((fs::path(dir) / name_).string(), width, height, fps_);
  }
  bool isOpen() const { return gif_.has_value(); }
  void add(const host::ImageView& im) { gif_->add(rgb8(im).data()); }
  void close() {
    gif_->close();
    gif_.reset();
    closed_ = true;
  }
  std::vector<std::string> wrote() const { return closed_ ? std::vector<std::string>{name_} : std::vector<std::string>{}; }

private:
  std::string name_;
  double fps_;
  std::optional<AnimatedGif> gif_;
  bool closed_ = false;
};

// buildup.gif: every run.buildup_every-th frame's image as it came, then the
// image after the final passes.
class BuildupSink final : public host::Sink {
public:
  explicit BuildupSink(const host::RunJob& j) : j_(j), gif_("buildup.gif", j.buildupFps) {}
  void start(const host::RunStart& r) override { gif_.open(j_.outDir, r.width, r.height); }
  void image(const host::ImageView& im) override {
    if (!gif_.isOpen() || !im.latest || floorDiv(im.frame, j_.buildupEvery) <= floorDiv(last_, j_.buildupEvery))
      return;
    gif_.add(im);
    last_ = im.frame;
  }
  void finished(const host::ImageView& im) override {
    gif_.add(im);
    gif_.close();
  }
  std::vector<std::string> wrote() const override { return gif_.wrote(); }

private:
  const host::RunJob& j_;
  Animation gif_;
  std::int64_t last_ = -1;
};

// final_<mode>.png for each mode of render.compositing.
class FinalImagesSink final : public host::Sink {
public:
  explicit FinalImagesSink(const host::RunJob& j) : j_(j) {}
  void finalImage(pp::CompositeMode mode, const host::ImageView& im) override {
    const std::string name = "final_" + std::string(enumName(mode)) + ".png";
    writeRgbPng((fs::path(j_.outDir) / name).string(), im.width, im.height, rgb8(im).data());
    wrote_.push_back(name);
  }
  std::vector<std::string> wrote() const override { return wrote_; }

private:
  const host::RunJob& j_;
  std::vector<std::string> wrote_;
};

// orbit.gif: the final volume turned about the vertical axis (run.orbit_frames views).
class OrbitSink final : public host::Sink {
public:
  explicit OrbitSink(const host::RunJob& j) : j_(j), gif_("orbit.gif", j.orbitFps) {}
  void orbit(int i, int n, const host::ImageView& im) override {
    if (i == 0) gif_.open(j_.outDir, im.width, im.height);
    gif_.add(im);
    if (i + 1 == n) gif_.close();
  }
  std::vector<std::string> wrote() const override { return gif_.wrote(); }

private:
  const host::RunJob& j_;
  Animation gif_;
};

}  // namespace

std::unique_ptr<host::Sink> makeBuildupSink(const host::RunJob& job) { return std::make_unique<BuildupSink>(job); }
std::unique_ptr<host::Sink> makeFinalImagesSink(const host::RunJob& job) {
  return std::make_unique<FinalImagesSink>(job);
}
std::unique_ptr<host::Sink> makeOrbitSink(const host::RunJob& job) {
  if (job.orbitFrames <= 0) return nullptr;
  return std::make_unique<OrbitSink>(job);
}

}  // namespace pp5::outputs
