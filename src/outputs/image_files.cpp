// The run's images as files: the build-up animation, the final image of each
// composition mode and the rotating loop.
#include <filesystem>
#include <memory>
#include <optional>

#include "core/image_io.hpp"
#include "core/enum_names.hpp"
#include "host/run_loop.hpp"
#include "pp/tile_caches.hpp"

namespace pp5::outputs {

namespace {

namespace fs = std::filesystem;

std::vector<std::uint8_t> rgb8(const host::ImageView& im) {
  return pp::toRgb8(pp::TileImage{im.width, im.height, *im.rgba});
}

// floor(a / b) for b > 0, so that frame -1 (none yet) counts below frame 0.
std::int64_t floorDiv(std::int64_t a, std::int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

// buildup.gif: every run.buildup_every-th frame's image as it came, then the
// image after the final passes.
class BuildupSink final : public host::Sink {
public:
  explicit BuildupSink(const host::RunJob& j) : j_(j) {}
  void start(const host::RunStart& r) override {
    gif_.emplace((fs::path(j_.outDir) / "buildup.gif").string(), r.width, r.height, j_.buildupFps);
  }
  void image(const host::ImageView& im) override {
    if (!gif_ || !im.latest || floorDiv(im.frame, j_.buildupEvery) <= floorDiv(last_, j_.buildupEvery)) return;
    gif_->add(rgb8(im).data());
    last_ = im.frame;
  }
  void finished(const host::ImageView& im) override {
    gif_->add(rgb8(im).data());
    gif_->close();
    gif_.reset();
    wrote_ = true;
  }
  std::vector<std::string> wrote() const override {
    return wrote_ ? std::vector<std::string>{"buildup.gif"} : std::vector<std::string>{};
  }

private:
  const host::RunJob& j_;
  std::optional<AnimatedGif> gif_;
  std::int64_t last_ = -1;
  bool wrote_ = false;
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
  explicit OrbitSink(const host::RunJob& j) : j_(j) {}
  void orbit(int i, int n, const host::ImageView& im) override {
    if (i == 0) gif_.emplace((fs::path(j_.outDir) / "orbit.gif").string(), im.width, im.height, j_.orbitFps);
    gif_->add(rgb8(im).data());
    if (i + 1 == n) {
      gif_->close();
      gif_.reset();
      wrote_ = true;
    }
  }
  std::vector<std::string> wrote() const override {
    return wrote_ ? std::vector<std::string>{"orbit.gif"} : std::vector<std::string>{};
  }

private:
  const host::RunJob& j_;
  std::optional<AnimatedGif> gif_;
  bool wrote_ = false;
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
