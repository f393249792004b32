// The live viewer as a sink (outputs/live_view.hpp): what the pipeline makes,
// streamed to browsers, and what they change, handed back as the run's steering.
#include <cstdio>
#include <memory>

#include "outputs/live_view.hpp"
#include "host/run_loop.hpp"
#include "outputs/sinks.hpp"

namespace pp5::outputs {

namespace {

class ViewerSink final : public host::Sink, public host::Steering {
public:
  explicit ViewerSink(const host::RunJob& j)
      : live_(j.view, j.grid, j.pipeline.render, j.pipeline.recon, j.pipeline.tf,
              parallel::makeControlState(j.pipeline.render, j.pipeline.shading, j.pipeline.tf), j.outDir) {
    std::printf("viewer: open %s\n", live_.url().c_str());
    std::fflush(stdout);
  }
  void frame(const host::AcquiredFrame& a, std::uint64_t k) override {
    live_.frame(a.frame, a.imageToReference, k, a.timeS, a.arrival);
  }
  void epochStarted(std::uint32_t epoch, const host::ViewState& s, bool lasting) override {
    live_.epochStarted(epoch, s, lasting);
  }
  void image(const host::ImageView& im) override { live_.image(*im.rgba, im.width, im.height, im.epoch, im.frame); }
  bool wantsVolume() const override { return live_.wantsVolume(); }
  void volume(const Volume& v, std::uint64_t, const host::VolumeChange&) override { live_.volume(v); }
  void figures(const host::LiveFigures& f) override { live_.figures(f); }
  void inputEnded() override { live_.inputEnded(); }
  host::Steering* steering() override { return this; }

  std::uint64_t version() const override { return live_.version(); }
  host::LiveWanted wanted() const override { return live_.wanted(); }
  bool wantsImage() const override { return live_.wantsImage(); }
  bool servesFinal() const override { return live_.serve(); }
  void servingFinal() override {
    live_.servingFinal();
    std::printf("viewer: the final volume stays live at %s until Ctrl-C\n", live_.url().c_str());
    std::fflush(stdout);
  }

private:
  host::LiveView live_;
};

}  // namespace

std::unique_ptr<host::Sink> makeViewerSink(const host::RunJob& job) {
  if (job.view.listen.empty()) return nullptr;
  return std::make_unique<ViewerSink>(job);
}

}  // namespace pp5::outputs
