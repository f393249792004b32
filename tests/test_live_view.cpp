// The live viewer's host side without a browser: control messages checked
// field by field (a bad one changes nothing), the transfer-function ramp,
// scan coverage and the gap warning, and slices at display resolution.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <mutex>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.hpp"
#include "core/io_util.hpp"
#include "outputs/coverage.hpp"
#include "outputs/live_view.hpp"
#include "outputs/slices.hpp"
#include "pipeline/parallel_settings.hpp"
#include "viewer/drag_stride.hpp"
#include "viewer/rate_limit.hpp"
#include "ws_client.hpp"

namespace {

using namespace pp5;
using host::LiveView;

Grid smallGrid() {
  Grid g;
  g.dims = Index3(40, 30, 20);
  g.spacing = Vec3(1.0);
  g.origin = Vec3(0.0);
  return g;
}

struct Viewer {
  Grid grid = smallGrid();
  RenderSettings render;
  gp::ReconSettings recon;
  TransferFunctionSettings tf;
  comm::ControlState initial;
  std::unique_ptr<LiveView> live;
  Viewer() {
    render.width = render.height = 64;
    initial = parallel::makeControlState(render, gp::ShadeSettings{}, tf);
    host::ViewSettings vs;
    vs.listen = "127.0.0.1:0";
    live = std::make_unique<LiveView>(vs, grid, render, recon, tf, initial, ::testing::TempDir());
  }
};

TEST(LiveControls, BadMessagesGetAnErrorAndChangeNothing) {
  Viewer v;
  const comm::ControlState before = v.live->wanted().state;
  for (const char* bad : {
           "not json", "[1, 2]", "{\"no\": \"type\"}", "{\"type\": 3}", "{\"type\": \"warp\"}",
           R"({"type": "view", "seq": 1, "azimuth": 10, "elevation": 95, "distance": 3, "pan": [0, 0], "interactive": false})",
           R"({"type": "view", "seq": 1, "azimuth": 10, "elevation": 5, "distance": 3, "pan": [0], "interactive": false})",
           R"({"type": "view", "seq": 1, "azimuth": "left", "elevation": 5, "distance": 3, "pan": [0, 0], "interactive": false})",
           R"({"type": "view", "seq": 1, "azimuth": 10, "elevation": 5, "distance": 3, "pan": [0, 0], "interactive": 1})",
           R"({"type": "view", "seq": 1, "azimuth": 10, "elevation": 5, "distance": 3, "pan": [0, 0], "interactive": false, "x": 1})",
           R"({"type": "tf", "level": 999, "window": 10, "opacity": 1})",
           R"({"type": "tf", "level": 100, "window": 10, "opacity": 1.5})",
           R"({"type": "tf", "preset": "no such preset"})",
           R"({"type": "composite", "mode": "brightest"})",
           R"({"type": "shading", "mode": "phong", "light": "sun", "light_azimuth": 0, "light_elevation": 0})",
           R"({"type": "mpr", "axis": 1.5, "position": 0.5})",
           R"({"type": "mpr", "axis": 3, "position": 0.5})",
           R"({"type": "value_window", "window": 0, "level": 100})",
           R"({"type": "record", "on": "yes"})",
           R"({"type": "pause", "now": true})"}) {
    const std::string err = v.live->control(bad);
    EXPECT_FALSE(err.empty()) << bad;
    EXPECT_EQ(parallel::controlChanges(before, v.live->wanted().state), 0u) << bad;
  }
  EXPECT_FALSE(v.live->wanted().paused);
  EXPECT_FALSE(v.live->wanted().recording);
}

TEST(LiveControls, GoodMessagesChangeWhatThePipelineIsAsked) {
  Viewer v;
  EXPECT_EQ(v.live->control(R"({"type": "view", "seq": 4, "azimuth": 10, "elevation": 5, "distance": 2.5,
                                "pan": [3, -2], "interactive": true})"),
            "");
  comm::ControlState s = v.live->wanted().state;
  EXPECT_EQ(s.azimuthDeg, 10.0);
  EXPECT_EQ(s.elevationDeg, 5.0);
  EXPECT_EQ(s.distance, 2.5);
  EXPECT_EQ(s.panMm[0], 3.0);
  EXPECT_EQ(s.stepScale, host::ViewSettings{}.dragStepScale);  // a drag: the coarser lattice
  EXPECT_EQ(s.pixelStride, host::ViewSettings{}.dragPixelStride);  // ... and fewer rays
  EXPECT_EQ(v.live->control(R"({"type": "view", "seq": 5, "azimuth": 10, "elevation": 5, "distance": 2.5,
                                "pan": [3, -2], "interactive": false})"),
            "");
  EXPECT_EQ(v.live->wanted().state.stepScale, 1.0);  // the mouse stopped: full resolution
  EXPECT_EQ(v.live->wanted().state.pixelStride, 1);

  EXPECT_EQ(v.live->control(R"({"type": "composite", "mode": "mip"})"), "");
  EXPECT_EQ(parallel::liveMode(v.live->wanted().state), CompositeMode::Mip);
  EXPECT_EQ(v.live->control(R"({"type": "value_window", "window": 100, "level": 80})"), "");
  EXPECT_EQ(v.live->wanted().state.valueWindow[0], 30.0);
  EXPECT_EQ(v.live->wanted().state.valueWindow[1], 130.0);

  EXPECT_EQ(v.live->control(R"({"type": "tf", "level": 100, "window": 40, "opacity": 0.5})"), "");
  s = v.live->wanted().state;
  ASSERT_EQ(s.opacityPoints, 4);
  EXPECT_EQ(s.opacity[1][0], 80.0);
  EXPECT_EQ(s.opacity[2][0], 120.0);
  EXPECT_EQ(s.opacity[2][1], 0.5);
  EXPECT_EQ(v.live->control(R"({"type": "tf", "preset": "strong echoes"})"), "");
  EXPECT_NE(v.live->wanted().state.opacity[1][0], 80.0);

  EXPECT_EQ(v.live->control(R"({"type": "pause"})"), "");
  EXPECT_TRUE(v.live->wanted().paused);
  EXPECT_EQ(v.live->control(R"({"type": "resume"})"), "");
  EXPECT_FALSE(v.live->wanted().paused);
  EXPECT_EQ(v.live->control(R"({"type": "record", "on": true})"), "");
  EXPECT_TRUE(v.live->wanted().recording);
  EXPECT_EQ(v.live->control(R"({"type": "mpr", "axis": 2, "position": 0.25})"), "");
}

TEST(LiveControls, TheRunsOwnChangesDoNotUndoThePages) {
  Viewer v;
  ASSERT_EQ(v.live->control(R"({"type": "composite", "mode": "additive"})"), "");
  // The run changes the view itself (an orbit frame) before it gets to the page's change.
  comm::ControlState orbit = v.initial;
  orbit.orbitValid = 1;
  orbit.orbitDeg = 40.0;
  v.live->epochStarted(1, orbit);
  EXPECT_EQ(parallel::liveMode(v.live->wanted().state), CompositeMode::Additive);
  // Once the pipeline made it, the run's next change is the page's new base.
  v.live->epochStarted(2, v.live->wanted().state);
  orbit.orbitDeg = 80.0;
  v.live->epochStarted(3, orbit);
  EXPECT_EQ(v.live->wanted().state.orbitDeg, 80.0);
}

// The final image of another mode is rendered live and undone: a change the
// page makes meanwhile is built on the lasting state, not on that one.
TEST(LiveControls, APassingChangeIsNoBaseForThePage) {
  Viewer v;
  comm::ControlState mip = v.initial;
  mip.liveMode = static_cast<std::uint8_t>(CompositeMode::Mip);
  v.live->epochStarted(1, mip, false);
  EXPECT_EQ(parallel::liveMode(v.live->wanted().state), parallel::liveMode(v.initial));
  ASSERT_EQ(v.live->control(R"({"type": "tf", "preset": "strong echoes"})"), "");
  v.live->epochStarted(2, v.initial, false);  // back to the live mode
  EXPECT_EQ(parallel::liveMode(v.live->wanted().state), parallel::liveMode(v.initial));
  ASSERT_EQ(v.live->control(R"({"type": "composite", "mode": "mip"})"), "");
  EXPECT_NE(parallel::controlChanges(v.initial, v.live->wanted().state) & comm::ControlMsg::kMode, 0u);
}

// (Each client's budget of control messages is the server's: ViewerServer.OneClientCannotSilenceAnother.)

TEST(LiveControls, ListenAddresses) {
  std::string a;
  int p = -1;
  io::parseListen("8080", a, p, "view.listen");
  EXPECT_EQ(a, "127.0.0.1");
  EXPECT_EQ(p, 8080);
  io::parseListen("0.0.0.0:0", a, p, "view.listen");
  EXPECT_EQ(a, "0.0.0.0");
  EXPECT_EQ(p, 0);
  io::parseListen("[::1]:9000", a, p, "view.listen");
  EXPECT_EQ(a, "::1");
  for (const char* bad : {"", "http", "127.0.0.1:", ":80", "127.0.0.1:70000", "8080x"})
    EXPECT_THROW(io::parseListen(bad, a, p, "view.listen"), InputError) << bad;
}

TEST(LiveControls, OpacityRampIsIncreasingAndClipped) {
  for (const auto& [level, window] : std::vector<std::pair<double, double>>{{128, 64}, {10, 100}, {250, 40}, {0, 1}}) {
    const auto pts = host::rampOpacity(level, window, 0.7);
    ASSERT_GE(pts.size(), 2u);
    EXPECT_EQ(pts.front().x, 0.0);
    EXPECT_EQ(pts.back().x, 255.0);
    for (std::size_t i = 1; i < pts.size(); ++i) EXPECT_GT(pts[i].x, pts[i - 1].x);
    for (const auto& p : pts) {
      const double want = 0.7 * std::clamp((p.x - (level - window / 2)) / window, 0.0, 1.0);
      EXPECT_NEAR(p.y, want, 1e-12);
    }
  }
}

// A frame of 20 x 10 pixels of 1 mm in the plane z = z0, its corner at (x0, 5).
Mat4 framePose(double x0, double z0) {
  Mat4 m(1.0);
  m[3] = Vec4(x0, 5.0, z0, 1.0);
  return m;
}

TEST(Coverage, SweptCellsGapsAndOutline) {
  const Grid g = smallGrid();
  gp::ReconSettings recon;
  recon.tent.fillInMaxGapMm = 6.0;
  host::Coverage cov(g, recon, 4.0);
  EXPECT_EQ(cov.fraction(), 0.0);
  cov.add(framePose(5.0, 10.0), 20, 10);
  const double one = cov.fraction();
  EXPECT_GT(one, 0.0);
  EXPECT_LT(one, 0.2);
  EXPECT_TRUE(cov.covered(Vec3(10.0, 8.0, 10.0)));
  EXPECT_FALSE(cov.covered(Vec3(10.0, 8.0, 2.0)));
  cov.add(framePose(5.0, 10.0), 20, 10);  // the same plane again: nothing new
  EXPECT_EQ(cov.fraction(), one);
  EXPECT_FALSE(cov.gapWarning());
  cov.add(framePose(5.0, 14.0), 20, 10);  // 4 mm on: fill-in reaches
  EXPECT_GT(cov.fraction(), one);
  EXPECT_NEAR(cov.lastGapMm(), 4.0, 1e-9);
  EXPECT_FALSE(cov.gapWarning());
  cov.add(framePose(5.0, 4.0), 20, 10);  // 10 mm back: too far, holes
  EXPECT_TRUE(cov.gapWarning());
  EXPECT_EQ(cov.gapLimitMm(), 6.0);

  // The outline: the frame's corners where the camera draws them.
  RenderSettings rs;
  rs.width = rs.height = 100;
  const Camera cam = makeCamera(rs, g);
  const auto corners = host::frameCorners(framePose(5.0, 10.0), 20, 10);
  const auto o = host::outlineOnScreen(cam, corners);
  ASSERT_TRUE(o.has_value());
  for (int i = 0; i < 4; ++i) {
    const auto p = cam.project(corners[static_cast<std::size_t>(i)]);
    EXPECT_NEAR((*o)[static_cast<std::size_t>(i)][0], p->px, 1e-9);
    EXPECT_GT((*o)[static_cast<std::size_t>(i)][0], 0.0);
    EXPECT_LT((*o)[static_cast<std::size_t>(i)][0], 100.0);
  }
}

TEST(Slices, DisplayResolutionWindowLevelAndOblique) {
  const Grid g = smallGrid();
  Volume v;
  v.allocate(g, ScalarType::F32);
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j)
      for (std::int64_t i = 0; i < g.dims.x; ++i) v.setValue(g.linear(i, j, k), 5.0 * static_cast<double>(i) + k);
  host::SliceLook look;
  look.longSide = 200;
  const host::SliceImage ax = host::slice(v, {host::SliceAxis::Axial, 0.5, 0.0}, look);
  EXPECT_EQ(ax.width, 200);   // 40 mm on the long side
  EXPECT_EQ(ax.height, 150);  // 30 mm: the proportions kept
  auto at = [](const host::SliceImage& im, int x, int y) { return im.rgb[(static_cast<std::size_t>(y) * im.width + x) * 3]; };
  // Trilinear: the grey level grows smoothly left to right (5 per mm).
  EXPECT_LT(at(ax, 20, 75), at(ax, 100, 75));
  EXPECT_NEAR(at(ax, 102, 75) - at(ax, 98, 75), 4.0 / 5.0 * 5.0, 1.01);
  // Window and level: level 100 window 50 maps 75..125 to black..white.
  look.window = 50;
  look.level = 100;
  const host::SliceImage wl = host::slice(v, {host::SliceAxis::Axial, 0.5, 0.0}, look);
  EXPECT_EQ(at(wl, 5, 75), 0);
  EXPECT_EQ(at(wl, 195, 75), 255);
  // Oblique: tilted, the slice meets other depths (the value grows with z).
  look = host::SliceLook{};
  look.longSide = 200;
  const host::SliceImage ob = host::slice(v, {host::SliceAxis::Coronal, 0.5, 30.0}, look);
  const host::SliceImage co = host::slice(v, {host::SliceAxis::Coronal, 0.5, 0.0}, look);
  EXPECT_EQ(ob.width, co.width);
  EXPECT_NE(ob.rgb, co.rgb);
  EXPECT_THROW(host::slice(v, {}, host::SliceLook{512, 0.0, 100.0}), InputError);
  // Coverage: what no frame swept is tinted.
  gp::ReconSettings recon;
  host::Coverage cov(g, recon, 4.0);
  cov.add(framePose(5.0, 10.0), 20, 10);
  const host::SliceImage tinted = host::slice(v, {host::SliceAxis::Axial, 0.5, 0.0}, look, &cov);
  const std::size_t far = (static_cast<std::size_t>(5) * tinted.width + 190) * 3;  // not swept
  EXPECT_GT(tinted.rgb[far], tinted.rgb[far + 1]);
}

}  // namespace

// The viewer's image rate: images that come at the rate, jittered, go at once
// (fixed slots would lock in a delay once one slot is missed); faster ones are
// held to the rate on average, with at most a burst of two.
TEST(ImageRate, JitteredImagesAtTheRateGoAtOnceAndFasterOnesAreHeld) {
  using viewer::RateLimit;
  using namespace std::chrono;
  const auto t0 = RateLimit::Clock::now();
  RateLimit r(30, 2, t0);
  const auto at = [&](double ms) { return t0 + duration_cast<RateLimit::Clock::duration>(duration<double, std::milli>(ms)); };
  // 300 images a period apart, each up to 10 ms early or late: none waits.
  for (int i = 0; i < 300; ++i) {
    const double jitter = (i % 3 == 0) ? -10 : (i % 3 == 1) ? 10 : 0;
    const auto t = at(1000.0 / 30 * i + jitter);
    EXPECT_EQ(r.wait(t), RateLimit::Clock::duration::zero()) << i;
    EXPECT_TRUE(r.take(t)) << i;
  }
  // Images every millisecond for a second: 30 go, plus the burst.
  RateLimit fast(30, 2, t0);
  int sent = 0;
  for (int i = 0; i <= 1000; ++i)
    if (fast.take(at(i))) ++sent;
  EXPECT_GE(sent, 31);
  EXPECT_LE(sent, 32);
  // After a burst, the wait is until the next credit.
  RateLimit b(10, 2, t0);
  EXPECT_TRUE(b.take(t0));
  EXPECT_TRUE(b.take(t0));
  EXPECT_FALSE(b.take(t0));
  const double waitMs = duration<double, std::milli>(b.wait(t0)).count();
  EXPECT_NEAR(waitMs, 100.0, 0.1);
  b.force(t0);  // a new view's image goes anyway, spending nothing it does not have
  EXPECT_TRUE(b.take(at(100)));
}

namespace {

// The headers of the images a WebSocket client gets from a LiveView, read on
// a thread of their own.
struct ImageWatcher {
  test::Client c;
  std::mutex m;
  std::vector<nlohmann::json> images;
  std::thread reader;
  bool watched = false;  // the viewer counts this client
  explicit ImageWatcher(const LiveView& live) {
    const std::string url = live.url();
    c.connect(std::stoi(url.substr(url.rfind(':') + 1)), "");
    for (int i = 0; i < 500 && !live.watched(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    watched = live.watched();
    reader = std::thread([this] {
      try {
        for (;;) {
          const std::string msg = c.read();
          std::uint32_t n = 0;
          for (int i = 0; i < 4; ++i) n |= static_cast<std::uint32_t>(static_cast<std::uint8_t>(msg[i])) << (8 * i);
          nlohmann::json h = nlohmann::json::parse(msg.substr(4, n));
          if (h["type"] == "image") {
            const std::lock_guard lock(m);
            images.push_back(std::move(h));
          }
        }
      } catch (...) {  // closed
      }
    });
  }
  ~ImageWatcher() {
    boost::system::error_code ec;
    c.ws.next_layer().shutdown(boost::asio::ip::tcp::socket::shutdown_both, ec);
    reader.join();
  }
  std::vector<nlohmann::json> got() {
    const std::lock_guard lock(m);
    return images;
  }
  bool waitForImages(std::size_t n) {
    for (int i = 0; i < 500; ++i) {
      if (got().size() >= n) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return false;
  }
};

}  // namespace

// In a drag, once the page has asked for a newer view, images of new frames
// in the view it left are held (they would take the CPU from making the views
// it asked for), though never more than 100 ms after the last image, so that
// a slow pipeline's frames still show; the new view's first image goes at once.
TEST(LiveImages, AViewThePageLeftGetsFewerImagesOfNewFrames) {
  Viewer v;
  ImageWatcher w(*v.live);
  ASSERT_TRUE(w.watched);
  const std::vector<float> rgba(64 * 64 * 4, 0.5f);
  const auto sentMs = [&](std::size_t i) { return w.got().at(i)["sent_ms"].get<std::int64_t>(); };
  v.live->epochStarted(1, v.initial);
  v.live->image(rgba, 64, 64, 1, 0);
  ASSERT_TRUE(w.waitForImages(1));
  EXPECT_EQ(w.got().back()["epoch"], 1);

  // The page drags; the pipeline hands over a new frame's image in the old view.
  ASSERT_EQ(v.live->control(R"({"type": "view", "seq": 1, "azimuth": 10, "elevation": 5, "distance": 2.5,
                                "pan": [0, 0], "interactive": true})"),
            "");
  v.live->image(rgba, 64, 64, 1, 1);
  ASSERT_TRUE(w.waitForImages(2));
  EXPECT_EQ(w.got().back()["frame"], 1);
  EXPECT_GE(sentMs(1) - sentMs(0), 75) << "frame 1's image in the view the page left went at once";
  // The asked view: its first image goes at once.
  v.live->epochStarted(2, v.live->wanted().state);
  v.live->image(rgba, 64, 64, 2, 1);
  ASSERT_TRUE(w.waitForImages(3));
  EXPECT_EQ(w.got().back()["epoch"], 2);
  EXPECT_EQ(w.got().back()["view_seq"], 1);
  // The page is where the pipeline is: a new frame's image goes too. (How
  // soon is the rate's matter, ImageRate; no upper bound on time here, where
  // a busy machine may stall any thread.)
  v.live->image(rgba, 64, 64, 2, 2);
  ASSERT_TRUE(w.waitForImages(4));
  EXPECT_EQ(w.got().back()["frame"], 2);
}

// An image's header names the preset its epoch shows: an epoch the run makes
// with its own opacity while the page's new preset waits is not labelled
// with the page's.
TEST(LiveImages, AnEpochIsLabelledWithThePresetItShows) {
  Viewer v;
  ImageWatcher w(*v.live);
  ASSERT_TRUE(w.watched);
  const std::vector<float> rgba(64 * 64 * 4, 0.5f);
  ASSERT_EQ(v.live->control(R"({"type": "tf", "preset": "strong echoes"})"), "");
  comm::ControlState orbit = v.initial;  // the run's own view change, its opacity the run's
  orbit.orbitValid = 1;
  orbit.orbitDeg = 40.0;
  v.live->epochStarted(1, orbit, false);
  v.live->image(rgba, 64, 64, 1, 0);
  ASSERT_TRUE(w.waitForImages(1));
  EXPECT_EQ(w.got().back()["preset"], "run");
  v.live->epochStarted(2, v.live->wanted().state);  // the page's
  v.live->image(rgba, 64, 64, 2, 0);
  ASSERT_TRUE(w.waitForImages(2));
  EXPECT_EQ(w.got().back()["preset"], "strong echoes");
  v.live->epochStarted(3, orbit, false);  // the run's again: back to its opacity
  v.live->image(rgba, 64, 64, 3, 0);
  ASSERT_TRUE(w.waitForImages(3));
  EXPECT_EQ(w.got().back()["preset"], "run");
}

// A page's view message: a drag's (interactive) or the one when the mouse stops.
std::string viewMessage(int seq, bool interactive) {
  return fmt::format(R"({{"type": "view", "seq": {}, "azimuth": {}, "elevation": 5, "distance": 2.5, "pan": [0, 0],
                         "interactive": {}}})",
                     seq, 10 + seq, interactive ? "true" : "false");
}

// A drag's stride follows how long its views take against 1 / view.drag_rate_hz.
TEST(DragStride, CoarserWhenSlowFinerWhenWellUnderNeverPastItsBounds) {
  viewer::DragStride d(2, 15);  // a budget of 66.7 ms
  EXPECT_EQ(d.stride(), 2);
  d.observe(2, 0.060);  // within the budget: kept
  EXPECT_EQ(d.stride(), 2);
  d.observe(2, 0.070);
  EXPECT_EQ(d.stride(), 4);
  d.observe(2, 0.500);  // a view asked for before the change: says nothing of stride 4
  EXPECT_EQ(d.stride(), 4);
  d.observe(4, 0.100);
  EXPECT_EQ(d.stride(), 8);
  d.observe(8, 0.300);  // as coarse as tiles allow
  EXPECT_EQ(d.stride(), 8);
  d.observe(8, 0.015);  // under a quarter of the budget, but one such view is not enough
  d.observe(8, 0.015);
  d.observe(8, 0.020);  // over a quarter: a finer one might not keep up; the count starts again
  d.observe(8, 0.015);
  d.observe(8, 0.015);
  EXPECT_EQ(d.stride(), 8);
  d.observe(8, 0.015);  // the third in a row
  EXPECT_EQ(d.stride(), 4);
  for (int i = 0; i < 2; ++i) d.observe(4, 0.001);
  EXPECT_EQ(d.stride(), 4);
  d.observe(4, 0.001);
  EXPECT_EQ(d.stride(), 2);
  for (int i = 0; i < 6; ++i) d.observe(2, 0.001);  // never finer than it started
  EXPECT_EQ(d.stride(), 2);

  viewer::DragStride fixed(4, 0);  // view.drag_rate_hz = 0
  fixed.observe(4, 10.0);
  EXPECT_EQ(fixed.stride(), 4);
}

// The host times a drag's view from its message's arrival (it may wait for
// the pipeline) to its image, and the page's next drag views get the stride
// that timing asks for; the image when the mouse stops is the full one
// whatever the stride.
TEST(DragStride, ASlowDragViewMakesTheNextOnesCoarser) {
  Viewer v;
  ImageWatcher w(*v.live);  // images are only made while a browser watches
  ASSERT_TRUE(w.watched);
  const std::vector<float> rgba(64 * 64 * 4, 0.5f);
  const auto drag = [&](int seq, bool interactive) { return v.live->control(viewMessage(seq, interactive)); };
  ASSERT_EQ(drag(1, true), "");
  EXPECT_EQ(v.live->wanted().state.pixelStride, 2);  // view.drag_pixel_stride
  // 80 ms in all, longer than 1 / 15 s, but only 30 of them after the
  // pipeline took the view.
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  v.live->epochStarted(1, v.live->wanted().state);
  std::this_thread::sleep_for(std::chrono::milliseconds(30));
  v.live->image(rgba, 64, 64, 1, 0);
  ASSERT_EQ(drag(2, true), "");
  EXPECT_EQ(v.live->wanted().state.pixelStride, 4);
  ASSERT_EQ(drag(3, false), "");  // the mouse stops
  EXPECT_EQ(v.live->wanted().state.pixelStride, 1);
  ASSERT_EQ(drag(4, true), "");  // the next drag starts where the last one ended
  EXPECT_EQ(v.live->wanted().state.pixelStride, 4);
}

// The page sends a view message every animation frame, so a newer one often
// comes while the host waits to send the one it fetched: that view is still
// the drag's, labelled with its own message and timed from its arrival.
TEST(DragStride, AViewThePageHasMovedOnFromIsStillTheDragsAndTimed) {
  Viewer v;
  ImageWatcher w(*v.live);
  ASSERT_TRUE(w.watched);
  const std::vector<float> rgba(64 * 64 * 4, 0.5f);
  ASSERT_EQ(v.live->control(viewMessage(1, true)), "");
  const comm::ControlState taken = v.live->wanted().state;  // the host fetches it ...
  std::this_thread::sleep_for(std::chrono::milliseconds(80));  // ... and waits for the GPs
  ASSERT_EQ(v.live->control(viewMessage(2, true)), "");  // the mouse moved on meanwhile
  v.live->epochStarted(1, taken);
  v.live->image(rgba, 64, 64, 1, 0);
  ASSERT_TRUE(w.waitForImages(1));
  EXPECT_EQ(w.got().back()["view_seq"], 1);
  EXPECT_EQ(w.got().back()["interactive"], true);
  ASSERT_EQ(v.live->control(viewMessage(3, true)), "");
  EXPECT_EQ(v.live->wanted().state.pixelStride, 4) << "the view's 80 ms were not counted";
}
