#include "outputs/live_view.hpp"
#include "outputs/live_view_impl.hpp"
#include "core/io_util.hpp"

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <atomic>
#include <deque>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <random>
#include <thread>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "core/config.hpp"
#include "core/error.hpp"
#include "rendering/shading.hpp"
#include "outputs/coverage.hpp"
#include "formats/recording_journal.hpp"
#include "host/recorder.hpp"
#include "outputs/slices.hpp"
#include "pipeline/parallel_settings.hpp"
#include "rendering/ray_cache.hpp"
#include "viewer/drag_stride.hpp"
#include "viewer/jpeg.hpp"
#include "viewer/rate_limit.hpp"
#include "viewer/viewer_server.hpp"

#ifndef PP5_WEB_ROOT
#define PP5_WEB_ROOT ""
#endif

namespace pp5::host {

using namespace live;

void registerOptions(ConfigSchema& c, ViewSettings& s) {
  c.section("view", "The live viewer: a web page served by the host while the run goes on (docs/viewer.md).");
  c.option("view.listen", &s.listen, "",
           "Serve the viewer at \"[ADDR:]PORT\" (address 127.0.0.1 unless given; port 0 = any free one); \"\" = no "
           "viewer. `run --view` sets it.");
  c.option("view.token", &s.token, "",
           "The token a browser must give (?token=...) when the address is not loopback; \"\" = a random one, "
           "printed with the URL.");
  c.option("view.serve", &s.serve, false,
           "Keep the final volume interactive after the input ends, until Ctrl-C (`run --serve`).");
  c.option("view.image_hz", &s.imageHz, 30.0, 1.0, 240.0, "At most this many 3D images per second to the browsers, on average (two may go back to back, so that an image that comes a little early is not held back).");
  c.option("view.jpeg_quality", &s.jpegQuality, 85, 10, 100, "JPEG quality of the streamed images.");
  c.option("view.bmode_hz", &s.bmodeHz, 15.0, 0.5, 240.0, "B-mode frames per second shown beside the 3D view.");
  c.option("view.slice_hz", &s.sliceHz, 2.0, 0.1, 30.0,
           "How often the slices (MPR) fetch the growing volume, at most, while a browser watches.");
  c.option("view.slice_size", &s.sliceSize, 384, 64, 4096, "Pixels on the longer side of the streamed slices.");
  c.option("view.drag_step_scale", &s.dragStepScale, 2.0, 1.0, 8.0,
           "While the user drags the view, the ray step is this many times longer (a faster, coarser image); "
           "the full one follows when the mouse stops.");
  c.option("view.drag_pixel_stride", &s.dragPixelStride, 2, 1, 8,
           "While the user drags the view, a ray for every n-th pixel (1, 2, 4 or 8) along x and y only: an image n times "
           "coarser, sent n x n times smaller and scaled up by the page (as ParaViewWeb does while one "
           "interacts); the full one follows when the mouse stops. The stride a drag starts at, and the finest "
           "view.drag_rate_hz goes back to.");
  c.option("view.drag_rate_hz", &s.dragRateHz, 15.0, 0.0, 120.0,
           "The views a second a drag aims at (15, VTK's interactor's desired update rate): a drag's view whose image "
           "takes longer than 1/rate makes the next ones twice as coarse (up to a stride of 8), three in a row under a "
           "quarter of it twice as fine again (down to view.drag_pixel_stride); the stride carries over to the next "
           "drag. 0: always view.drag_pixel_stride.");
  c.option("view.web_root", &s.webRoot, "", "The page's folder; \"\" = the one in the source tree (src/viewer/web).");
}

void checkViewSettings(const ViewSettings& s) {
  if (s.serve && s.listen.empty())
    throw InputError("view.serve (--serve) keeps the viewer's final volume live: give --view [ADDR:]PORT too");
  // Tiles are multiples of 8 pixels: a stride that divides 8 starts every tile
  // on a strided pixel, so each PP fills its blocks as the whole image would.
  if (8 % s.dragPixelStride != 0)
    throw InputError(fmt::format("view.drag_pixel_stride = {}: give 1, 2, 4 or 8", s.dragPixelStride));
}

std::vector<glm::dvec4> rampOpacity(double level, double window, double opacity) {
  const double lo = level - 0.5 * window, hi = level + 0.5 * window;
  auto at = [&](double v) { return opacity * std::clamp((v - lo) / (hi - lo), 0.0, 1.0); };
  std::vector<double> xs = {0.0, std::clamp(lo, 0.0, 255.0), std::clamp(hi, 0.0, 255.0), 255.0};
  std::vector<glm::dvec4> pts;
  for (const double x : xs)
    if (pts.empty() || x > pts.back().x) pts.emplace_back(x, at(x), 0.0, 0.0);
  return pts;
}

namespace {

std::string randomToken() {
  std::random_device rd;
  std::string t;
  for (int i = 0; i < 4; ++i) t += fmt::format("{:08x}", rd());
  return t;
}

}  // namespace


LiveView::LiveView(const ViewSettings& settings, const Grid& grid, const RenderSettings& base,
                   const gp::ReconSettings& recon, const TransferFunctionSettings& tf, const comm::ControlState& initial,
                   const std::string& recordDir)
    : impl_(std::make_unique<Impl>(settings, grid, base, recon, tf)) {
  checkViewSettings(settings);
  impl_->recordDir = recordDir;
  viewer::ServerOptions o;
  io::parseListen(settings.listen, o.address, o.port, "view.listen");
  o.root = settings.webRoot.empty() ? std::string(PP5_WEB_ROOT) : settings.webRoot;
  o.token = settings.token;
  if (o.token.empty() && !viewer::isLoopback(o.address)) o.token = randomToken();
  impl_->server = std::make_unique<viewer::Server>(o);
  Impl& I = *impl_;
  I.want.state = initial;
  const TransferFunctionSettings& t = tf;
  if (t.opacity.size() >= 2) {  // the page's sliders start near the run's ramp
    I.tfLevel = 0.5 * (t.opacity.front().x + t.opacity.back().x);
    I.tfWindow = std::max(1.0, t.opacity.back().x - t.opacity.front().x);
    I.tfOpacity = t.opacity.back().y;
  }
  I.epochs.push_back({0, parallel::controlCamera(initial, base, grid), 0, false, 1,
                      std::string(enumName(parallel::liveMode(initial))), I.preset, opacityOf(initial)});
  I.server->onMessage([&I](const std::string& m) { return I.control(m); });
  I.encoder = std::thread([&I] { I.run(); });
}

LiveView::~LiveView() {
  {
    const std::lock_guard lock(impl_->m);
    impl_->quit = true;
  }
  impl_->cv.notify_one();
  if (impl_->encoder.joinable()) impl_->encoder.join();
  impl_->server.reset();
}

std::string LiveView::url() const { return impl_->server->url(); }
bool LiveView::watched() const { return impl_->server->clients() > 0; }
bool LiveView::serve() const { return impl_->s.serve; }

void LiveView::frame(const Frame& f, const Mat4& pose, std::uint64_t k, double timeS, Clock::time_point arrival) {
  Impl& I = *impl_;
  const auto sysArrival = std::chrono::system_clock::now() -
                          std::chrono::duration_cast<std::chrono::system_clock::duration>(Clock::now() - arrival);
  std::string recording;
  {
    const std::lock_guard lock(I.m);
    recording = I.recording;
  }
  I.recorder.record(recording);  // the page started or stopped a recording, or neither
  I.recorder.writePlaced(f, pose, timeS);
  const std::lock_guard lock(I.m);
  I.coverage.add(pose, f.width, f.height);
  I.lastCorners = frameCorners(pose, f.width, f.height);
  I.haveCorners = true;
  I.frames = k + 1;
  I.arrivals.emplace_back(static_cast<std::int64_t>(k), unixMs(sysArrival));
  while (I.arrivals.size() > 128) I.arrivals.pop_front();
  const auto now = Clock::now();
  if (I.server->clients() > 0 && now - I.lastBmode >= std::chrono::duration<double>(1.0 / I.s.bmodeHz)) {
    I.lastBmode = now;
    I.pendingBmode = f;
    I.bmodeIndex = f.index;
    I.bmodeTime = timeS;
    I.bmodePending = true;
    I.cv.notify_one();
  }
}

void LiveView::epochStarted(std::uint32_t epoch, const comm::ControlState& state, bool lasting) {
  Impl& I = *impl_;
  const std::lock_guard lock(I.m);
  const bool asked = parallel::controlChanges(state, I.want.state) == 0;
  // The page's state as the host fetched it, when the page has sent a newer
  // one since: still the page's view (a drag's, most often).
  const bool handed = !asked && I.pageChange && parallel::controlChanges(state, I.handedState) == 0;
  // The view message it answers; none for a change of the run's own.
  const Impl::ViewAsked* answers = asked ? &I.wantView : handed ? &I.handedView : nullptr;
  const std::uint64_t seq = answers ? answers->seq : I.epochs.empty() ? 0 : I.epochs.back().seq;
  const bool interactive = answers && answers->interactive;
  if (asked) {
    I.pageChange = false;
  } else if (!I.pageChange && lasting) {  // (a handed view leaves pageChange set)
    // A change of the run's own (run.script, the final images, the orbit):
    // the page's next changes start from it. One the page asked for and the
    // pipeline has not yet made stays wanted.
    I.want.state = state;
    ++I.version;
  }
  // The preset it shows: the page's newest, unless the run made this epoch
  // with another opacity (the page's choice not yet applied): then that of
  // the last epoch with this one's, or the run's own.
  std::vector<double> opacity = opacityOf(state);
  std::string preset = I.preset;
  if (opacity != opacityOf(I.want.state)) {
    preset = "run";
    for (auto e = I.epochs.rbegin(); e != I.epochs.rend(); ++e)
      if (e->opacity == opacity) {
        preset = e->preset;
        break;
      }
  }
  if (interactive)
    I.dragTiming = {epoch, std::max(1, static_cast<int>(state.pixelStride)), std::max(answers->at, I.lastViewImage)};
  I.epochs.push_back({epoch, parallel::controlCamera(state, I.base, I.grid), seq, interactive,
                      std::max(1, static_cast<int>(state.pixelStride)), std::string(enumName(parallel::liveMode(state))),
                      std::move(preset), std::move(opacity)});
  while (I.epochs.size() > 8) I.epochs.pop_front();
}

void LiveView::image(const std::vector<float>& rgba, int width, int height, std::uint32_t epoch, std::int64_t frame) {
  Impl& I = *impl_;
  if (I.server->clients() == 0) return;
  const std::lock_guard lock(I.m);
  if (epoch != I.imageEpoch) {  // an epoch's first image: the host may send the next view
    const auto now = Clock::now();
    I.lastViewImage = now;
    if (I.dragTiming.stride > 0 && epoch == I.dragTiming.epoch) {
      I.dragStride.observe(I.dragTiming.stride, std::chrono::duration<double>(now - I.dragTiming.started).count());
      I.dragTiming.stride = 0;
    }
  }
  I.needImage = false;
  I.pendingImage.assign(rgba.begin(), rgba.end());
  I.imageW = width;
  I.imageH = height;
  I.imageEpoch = epoch;
  I.imageFrame = frame;
  I.imageAssembledMs = unixMs(std::chrono::system_clock::now());
  I.imagePending = true;
  I.cv.notify_one();
}

bool LiveView::wantsImage() const {
  if (impl_->server->clients() == 0) return false;
  const std::lock_guard lock(impl_->m);
  return impl_->needImage;
}

bool LiveView::wantsVolume() const {
  Impl& I = *impl_;
  if (I.server->clients() == 0) return false;
  const std::lock_guard lock(I.m);
  return (I.frames > I.framesAtVolume || I.pendingVolume.bytes.empty()) &&
         Clock::now() - I.lastVolume >= std::chrono::duration<double>(1.0 / I.s.sliceHz);
}

void LiveView::volume(const Volume& v) {
  Impl& I = *impl_;
  const std::lock_guard lock(I.m);
  I.pendingVolume = v;
  I.volumePending = true;
  I.lastVolume = Clock::now();
  I.framesAtVolume = I.frames;
  I.cv.notify_one();
}

void LiveView::figures(const LiveFigures& f) {
  const std::lock_guard lock(impl_->m);
  impl_->fig = f;
  impl_->statsDirty = true;  // sent with the encoder's next pass
}

void LiveView::inputEnded() {
  // The recording complete on disk before the run goes on; a frame that could
  // not be written fails the run, as it would have at frame().
  impl_->recorder.finish();
  const std::lock_guard lock(impl_->m);
  impl_->recording.clear();
  impl_->want.recording = false;
  ++impl_->version;
  impl_->ended = true;
  impl_->statsDirty = true;
  impl_->cv.notify_one();
}

void LiveView::servingFinal() {
  const std::lock_guard lock(impl_->m);
  impl_->serving = true;
  impl_->statsDirty = true;
  impl_->cv.notify_one();
}


std::uint64_t LiveView::version() const { return impl_->version.load(); }

LiveWanted LiveView::wanted() const {
  Impl& I = *impl_;
  const std::lock_guard lock(I.m);
  I.handedState = I.want.state;
  I.handedView = I.wantView;
  return I.want;
}

std::string LiveView::control(const std::string& json) { return impl_->control(json); }

}  // namespace pp5::host
