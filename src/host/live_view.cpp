#include "host/live_view.hpp"

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
#include "gp/shading.hpp"
#include "host/coverage.hpp"
#include "core/recording_journal.hpp"
#include "host/recorder.hpp"
#include "host/slices.hpp"
#include "parallel/parallel_settings.hpp"
#include "pp/ray_cache.hpp"
#include "viewer/drag_stride.hpp"
#include "viewer/jpeg.hpp"
#include "viewer/rate_limit.hpp"
#include "viewer/viewer_server.hpp"

#ifndef PP5_WEB_ROOT
#define PP5_WEB_ROOT ""
#endif

namespace pp5::host {

using json = nlohmann::json;

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

void parseListen(const std::string& listen, std::string& address, int& port, const std::string& what) {
  const auto colon = listen.rfind(':');
  address = colon == std::string::npos ? "127.0.0.1" : listen.substr(0, colon);
  const std::string p = colon == std::string::npos ? listen : listen.substr(colon + 1);
  if (address.size() > 2 && address.front() == '[' && address.back() == ']') address = address.substr(1, address.size() - 2);
  char* end = nullptr;
  const long v = std::strtol(p.c_str(), &end, 10);
  if (p.empty() || address.empty() || *end != '\0' || v < 0 || v > 65535)
    throw InputError(fmt::format("{} = \"{}\": give [ADDRESS:]PORT, e.g. 8080 or 127.0.0.1:8080 (port 0..65535)",
                                 what, listen));
  port = static_cast<int>(v);
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

std::int64_t unixMs(std::chrono::system_clock::time_point t) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(t.time_since_epoch()).count();
}

// One message: a little-endian u32 header length, the JSON header, the payload.
std::string pack(const json& header, const std::string& payload = {}) {
  const std::string h = header.dump();
  std::string out(4, '\0');
  const auto n = static_cast<std::uint32_t>(h.size());
  for (int i = 0; i < 4; ++i) out[static_cast<std::size_t>(i)] = static_cast<char>((n >> (8 * i)) & 0xFF);
  out += h;
  out += payload;
  return out;
}

enum Channel { kImage = 0, kBmode = 1, kStats = 2, kState = 3, kSlice0 = 4 };

struct Preset {
  const char* name;
  double level, window, opacity;
};
// A view the page has left gets no images of new frames (see the encoder's
// loop) for this long after the page's last change (longer than a drag's
// moves are apart), and for no longer than this after the last image sent.
constexpr std::chrono::milliseconds kLeftViewHold{250};
constexpr std::chrono::milliseconds kLeftViewGap{100};

// Ramps over the grey levels of B-mode echoes; "run" is the run's own transfer function.
constexpr Preset kPresets[] = {{"soft tissue", 70.0, 90.0, 0.35}, {"strong echoes", 150.0, 80.0, 0.9},
                               {"all echoes", 40.0, 60.0, 0.15}};

std::vector<double> opacityOf(const comm::ControlState& c) {
  const int n = std::clamp(c.opacityPoints, 0, comm::ControlState::kMaxPoints);
  return {&c.opacity[0][0], &c.opacity[0][0] + 2 * n};
}

// The range check every number in a control message passes.
double number(const json& m, const char* key, double lo, double hi) {
  const auto it = m.find(key);
  if (it == m.end()) throw InputError(fmt::format("\"{}\" is missing", key));
  if (!it->is_number()) throw InputError(fmt::format("\"{}\" must be a number", key));
  const double v = it->get<double>();
  if (!std::isfinite(v) || v < lo || v > hi) throw InputError(fmt::format("\"{}\" = {}: must be in {} .. {}", key, v, lo, hi));
  return v;
}
bool boolean(const json& m, const char* key) {
  const auto it = m.find(key);
  if (it == m.end() || !it->is_boolean()) throw InputError(fmt::format("\"{}\" must be true or false", key));
  return it->get<bool>();
}
std::string text(const json& m, const char* key) {
  const auto it = m.find(key);
  if (it == m.end() || !it->is_string()) throw InputError(fmt::format("\"{}\" must be a string", key));
  return it->get<std::string>();
}
void onlyKeys(const json& m, std::initializer_list<const char*> keys) {
  for (auto it = m.begin(); it != m.end(); ++it) {
    if (it.key() == "type") continue;
    if (std::none_of(keys.begin(), keys.end(), [&](const char* k) { return it.key() == k; }))
      throw InputError(fmt::format("unknown field \"{}\"", it.key()));
  }
}

std::string randomToken() {
  std::random_device rd;
  std::string t;
  for (int i = 0; i < 4; ++i) t += fmt::format("{:08x}", rd());
  return t;
}

}  // namespace

struct LiveView::Impl {
  ViewSettings s;
  Grid grid;
  RenderSettings base;
  TransferFunctionSettings runTf;
  std::unique_ptr<viewer::Server> server;

  mutable std::mutex m;
  std::condition_variable cv;
  bool quit = false;

  // What the browsers want (guarded by m).
  LiveWanted want;
  // A page's view message, as an epoch that answers it is labelled and timed.
  struct ViewAsked {
    std::uint64_t seq = 0;
    bool interactive = false;
    Clock::time_point at{};  // its arrival
  };
  ViewAsked wantView;  // the newest view message (its seq: the largest yet)
  // What the host last fetched (wanted()): a page's message newer than it
  // may come before the pipeline starts the epoch that answers it.
  comm::ControlState handedState;
  ViewAsked handedView;
  // A drag's stride (view.drag_rate_hz), and the drag's view being timed:
  // from its message's arrival, or the last view's first image if that came
  // later (the host sends a view once the last one's image is in), to its
  // image: the time between a drag's images on the page.
  viewer::DragStride dragStride;
  Clock::time_point lastViewImage{};  // the first image of the newest epoch that has one
  struct DragTiming {
    std::uint32_t epoch = 0;
    int stride = 0;  // 0 = none timed
    Clock::time_point started{};
  } dragTiming;
  bool pageChange = false;  // the page changed `want` and the pipeline has not caught up
  Clock::time_point pageChangeAt{};  // when it last did
  std::atomic<std::uint64_t> version{1};  // bumped with every change of `want`
  std::string preset = "run";
  double tfLevel = 128, tfWindow = 128, tfOpacity = 1;
  SlicePlane planes[3] = {{SliceAxis::Axial, 0.5, 0}, {SliceAxis::Coronal, 0.5, 0}, {SliceAxis::Sagittal, 0.5, 0}};
  SliceLook sliceLook;
  bool coverageMap = true;
  bool slicesDirty = false;
  std::deque<Clock::time_point> recent;  // control messages in the last second (rate bound)

  // Per epoch: the camera, the view message it answers, whether it is a drag's image.
  struct EpochView {
    std::uint32_t epoch;
    Camera camera;
    std::uint64_t seq;
    bool interactive;
    int stride;                     // the lattice's pixel stride
    std::string composite, preset;  // what the page may wait for
    std::vector<double> opacity;    // the epoch's opacity points, flat (which preset it shows)
  };
  std::deque<EpochView> epochs;

  // From the pipeline (guarded by m), waiting for the encoder.
  Coverage coverage;
  std::array<Vec3, 4> lastCorners{};
  bool haveCorners = false;
  std::deque<std::pair<std::int64_t, std::int64_t>> arrivals;  // (frame, unix ms)
  std::vector<float> pendingImage;
  int imageW = 0, imageH = 0;
  std::uint32_t imageEpoch = 0;
  std::int64_t imageFrame = -1;
  std::int64_t imageAssembledMs = 0;  // unix ms when the pipeline handed it over
  bool imagePending = false;
  bool needImage = false;  // a new browser: the host's current image, please
  Frame pendingBmode;
  std::uint64_t bmodeIndex = 0;
  double bmodeTime = 0;
  bool bmodePending = false;
  Clock::time_point lastBmode{};
  Volume pendingVolume;
  bool volumePending = false;
  Clock::time_point lastVolume{};
  std::uint64_t framesAtVolume = 0, frames = 0;
  LiveFigures fig;
  bool ended = false;
  bool serving = false;  // the final volume, steered by the page
  std::string recording;  // the page's recording: its file, "" = none (guarded by m)
  std::string recordDir;
  int recordings = 0;
  // The page's recording, written on its own thread so that the host's loop
  // never waits for the disk; asked for on the caller's thread only (frame(),
  // inputEnded()).
  RecorderThread recorder;
  bool statsDirty = true;

  std::thread encoder;

  Impl(const ViewSettings& settings, const Grid& g, const RenderSettings& b, const gp::ReconSettings& recon,
       const TransferFunctionSettings& tf)
      : s(settings), grid(g), base(b), runTf(tf), dragStride(settings.dragPixelStride, settings.dragRateHz),
        coverage(g, recon) {}

  // ---- control messages (the server's thread) ----
  std::string control(const std::string& textIn) {
    const std::lock_guard lock(m);
    const auto now = Clock::now();
    while (!recent.empty() && now - recent.front() > std::chrono::seconds(1)) recent.pop_front();
    if (recent.size() >= static_cast<std::size_t>(s.maxControlPerSecond))
      return fmt::format("too many control messages: at most {} a second", s.maxControlPerSecond);
    recent.push_back(now);
    json msg;
    try {
      msg = json::parse(textIn);
    } catch (const json::exception&) {
      return "a control message must be a JSON object";
    }
    if (!msg.is_object() || !msg.contains("type") || !msg["type"].is_string())
      return "a control message must be a JSON object with a string \"type\"";
    const std::string type = msg["type"].get<std::string>();
    LiveWanted next = want;  // changed only when the whole message is valid
    comm::ControlState& c = next.state;
    try {
      if (type == "view") {
        onlyKeys(msg, {"seq", "azimuth", "elevation", "distance", "pan", "interactive"});
        const auto seq = static_cast<std::uint64_t>(number(msg, "seq", 0, 1e15));
        c.azimuthDeg = number(msg, "azimuth", -360, 360);
        c.elevationDeg = number(msg, "elevation", -89, 89);
        c.distance = number(msg, "distance", 0.2, 50);
        const auto pan = msg.find("pan");
        if (pan == msg.end() || !pan->is_array() || pan->size() != 2 || !(*pan)[0].is_number() ||
            !(*pan)[1].is_number())
          throw InputError("\"pan\" must be [right_mm, up_mm]");
        for (int i = 0; i < 2; ++i) {
          const double v = (*pan)[static_cast<std::size_t>(i)].get<double>();
          if (!std::isfinite(v) || std::abs(v) > 1e4) throw InputError("\"pan\": each value in -10000 .. 10000 mm");
          c.panMm[i] = v;
        }
        const bool interactive = boolean(msg, "interactive");
        c.stepScale = interactive ? s.dragStepScale : 1.0;
        c.pixelStride = static_cast<std::uint8_t>(interactive ? dragStride.stride() : 1);
        c.orbitValid = 0;
        wantView = {std::max(wantView.seq, seq), interactive, now};
      } else if (type == "tf") {
        if (msg.contains("preset")) {
          onlyKeys(msg, {"preset"});
          const std::string p = text(msg, "preset");
          TransferFunctionSettings tf = runTf;
          if (p != "run") {
            const auto it = std::find_if(std::begin(kPresets), std::end(kPresets), [&](const Preset& q) { return p == q.name; });
            if (it == std::end(kPresets)) throw InputError(fmt::format("no transfer-function preset \"{}\"", p));
            tf.opacity = rampOpacity(it->level, it->window, it->opacity);
            tfLevel = it->level, tfWindow = it->window, tfOpacity = it->opacity;
          }
          setTf(c, tf);
          preset = p;
        } else {
          onlyKeys(msg, {"level", "window", "opacity"});
          const double level = number(msg, "level", 0, 255), window = number(msg, "window", 1, 510),
                       opacity = number(msg, "opacity", 0, 1);
          tfLevel = level, tfWindow = window, tfOpacity = opacity;
          TransferFunctionSettings tf = runTf;
          tf.opacity = rampOpacity(tfLevel, tfWindow, tfOpacity);
          setTf(c, tf);
          preset = "custom";
        }
      } else if (type == "composite") {
        onlyKeys(msg, {"mode"});
        c.liveMode = static_cast<std::uint8_t>(enumFromName<pp::CompositeMode>(text(msg, "mode"), "mode"));
      } else if (type == "value_window") {
        onlyKeys(msg, {"window", "level"});
        const double window = number(msg, "window", 1, 65535), level = number(msg, "level", 0, 65535);
        c.valueWindow[0] = std::max(0.0, level - 0.5 * window);
        c.valueWindow[1] = level + 0.5 * window;
      } else if (type == "shading") {
        onlyKeys(msg, {"mode", "light", "light_azimuth", "light_elevation"});
        const auto sm = enumFromName<gp::ShadeMode>(text(msg, "mode"), "mode");
        const auto lk = enumFromName<gp::LightKind>(text(msg, "light"), "light");
        const double az = glm::radians(number(msg, "light_azimuth", -180, 180));
        const double el = glm::radians(number(msg, "light_elevation", -90, 90));
        c.shadeMode = static_cast<std::uint8_t>(sm);
        c.light = static_cast<std::uint8_t>(lk);
        // From the light towards the scene.
        c.lightDirection[0] = -std::cos(el) * std::cos(az);
        c.lightDirection[1] = -std::cos(el) * std::sin(az);
        c.lightDirection[2] = -std::sin(el);
      } else if (type == "mpr") {
        onlyKeys(msg, {"axis", "position"});
        const double a = number(msg, "axis", 0, 2);
        if (a != std::floor(a)) throw InputError("\"axis\" must be 0, 1 or 2");
        const double position = number(msg, "position", 0, 1);
        planes[static_cast<int>(a)].position = position;
        slicesDirty = true;
      } else if (type == "mpr_window") {
        onlyKeys(msg, {"window", "level"});
        const double window = number(msg, "window", 1, 65535), level = number(msg, "level", -65535, 65535);
        sliceLook.window = window;
        sliceLook.level = level;
        slicesDirty = true;
      } else if (type == "mpr_tilt") {
        onlyKeys(msg, {"degrees"});
        const double t = number(msg, "degrees", -89, 89);
        for (SlicePlane& p : planes) p.tiltDeg = t;
        slicesDirty = true;
      } else if (type == "coverage_map") {
        onlyKeys(msg, {"on"});
        coverageMap = boolean(msg, "on");
        slicesDirty = true;
      } else if (type == "pause" || type == "resume") {
        onlyKeys(msg, {});
        next.paused = type == "pause";
      } else if (type == "record") {
        onlyKeys(msg, {"on"});
        next.recording = boolean(msg, "on");
        // A new name each time: never over an earlier recording, nor over the
        // journal of one that was cut off.
        while (next.recording && recording.empty()) {
          const std::string p =
              (std::filesystem::path(recordDir) / fmt::format("recording-{}.mha", ++recordings)).string();
          if (!std::filesystem::exists(p) && !std::filesystem::exists(journalPathFor(p))) recording = p;
        }
        if (!next.recording) recording.clear();
      } else {
        return fmt::format("unknown control message type \"{}\"", type);
      }
    } catch (const InputError& e) {
      return fmt::format("{}: {}", type, e.what());
    }
    if (parallel::controlChanges(want.state, next.state)) {
      pageChange = true;
      pageChangeAt = Clock::now();
    }
    want = next;
    ++version;
    statsDirty = true;
    cv.notify_one();
    return {};
  }

  static void setTf(comm::ControlState& c, const TransferFunctionSettings& tf) {
    c.opacityPoints = static_cast<std::int32_t>(std::min<std::size_t>(tf.opacity.size(), comm::ControlState::kMaxPoints));
    for (int i = 0; i < c.opacityPoints; ++i) {
      c.opacity[i][0] = tf.opacity[static_cast<std::size_t>(i)].x;
      c.opacity[i][1] = tf.opacity[static_cast<std::size_t>(i)].y;
    }
  }

  // ---- the encoder's thread ----
  json stateJson() const {
    const comm::ControlState& c = want.state;
    json presets = json::array({"run"});
    for (const Preset& p : kPresets) presets.push_back(p.name);
    return {{"type", "state"},
            {"azimuth", c.azimuthDeg},
            {"elevation", c.elevationDeg},
            {"distance", c.distance},
            {"pan", {c.panMm[0], c.panMm[1]}},
            {"composite", enumName(static_cast<pp::CompositeMode>(c.liveMode))},
            {"shading", enumName(static_cast<gp::ShadeMode>(c.shadeMode))},
            {"presets", presets},
            {"preset", preset},
            {"tf_level", tfLevel},
            {"tf_window", tfWindow},
            {"tf_opacity", tfOpacity},
            {"value_window", c.valueWindow[1] - c.valueWindow[0]},
            {"value_level", 0.5 * (c.valueWindow[0] + c.valueWindow[1])},
            {"mpr_window", sliceLook.window},
            {"mpr_level", sliceLook.level}};
  }

  json statsJson() const {
    return {{"type", "stats"},
            {"frames", fig.frames},
            {"frames_per_s", fig.framesPerS},
            {"images_per_s", fig.imagesPerS},
            {"latency_ms_median", fig.latencyMedianMs},
            {"latency_ms_p95", fig.latencyP95Ms},
            {"dropped", fig.dropped},
            {"gp_load", fig.gpLoad},
            {"pp_load", fig.ppLoad},
            {"coverage", coverage.fraction()},
            {"gap_mm", coverage.lastGapMm()},
            {"gap_limit_mm", coverage.gapLimitMm()},
            {"gap_warning", coverage.gapWarning()},
            {"paused", want.paused},
            {"recording", recording},
            {"ended", ended},
            {"serving", serving}};
  }

  void run() {
    viewer::JpegEncoder jpeg;
    std::string lastImage, lastBmodeMsg, lastSlices[3];
    std::size_t clients = 0;
    Clock::time_point lastStats{};
    viewer::RateLimit rate(s.imageHz, 2, Clock::now());  // a burst of 2 passes: see rate_limit.hpp
    std::uint32_t lastEpoch = UINT32_MAX;  // of the last image encoded
    Clock::time_point lastSentAt{};  // when it went
    // The slices being made (axis 3: none), from a copy of the volume.
    int sliceAxis = 3;
    Volume sliceVolume;
    SlicePlane slicePlanes[3];
    SliceLook sliceLookNow;
    bool sliceWithCoverage = false;
    std::unique_lock lock(m);
    Coverage sliceCoverage = coverage;
    while (!quit) {
      // Wake for work; the first image of a new view (a drag's answer) goes
      // out at once, whatever the rate. A view the page has already left (it
      // asked for a newer one that the pipeline has not made yet) gets fewer
      // images of new frames: in a drag they take the CPU (the JPEG here, the
      // decoding in the browser) from making the views asked for. Held only
      // a while after the page's change (should the pipeline never match it)
      // and after the last image (a slow pipeline's frames still show).
      const auto heldUntil = [&] {
        return pageChange ? std::min(pageChangeAt + kLeftViewHold, lastSentAt + kLeftViewGap) : Clock::time_point{};
      };
      const Clock::time_point now = Clock::now(), held = heldUntil();
      const bool newView = imagePending && imageEpoch != lastEpoch;
      const Clock::duration untilImage = !imagePending          ? std::chrono::milliseconds(100)
                                         : !newView && held > now ? held - now
                                                                  : rate.wait(now);
      if (!newView && sliceAxis == 3 && untilImage > Clock::duration::zero())
        cv.wait_for(lock, std::min<Clock::duration>(untilImage, std::chrono::milliseconds(100)));
      if (quit) break;
      const std::size_t nowClients = server->clients();
      const bool newClient = nowClients > clients;
      clients = nowClients;
      if (!clients) {
        // Nobody to send it to (a new client asks anew: needImage); slices
        // being made are given up, to be made again for the next client.
        imagePending = false;
        if (sliceAxis < 3) {
          sliceAxis = 3;
          sliceVolume = {};
          slicesDirty = true;
        }
        continue;
      }
      if (newClient) {  // what it missed: the newest of each
        needImage = true;
        for (auto* msg : {&lastImage, &lastBmodeMsg, &lastSlices[0], &lastSlices[1], &lastSlices[2]})
          if (!msg->empty()) server->publish(msg == &lastImage ? kImage : msg == &lastBmodeMsg ? kBmode
                                                                           : kSlice0 + static_cast<int>(msg - lastSlices),
                                             *msg);
        statsDirty = true;
      }
      bool sendImage = false;
      const Clock::time_point at = Clock::now();
      if (imagePending && imageEpoch != lastEpoch) {
        rate.force(at);
        sendImage = true;
      } else if (imagePending && at >= heldUntil()) {
        sendImage = rate.take(at);
      }
      if (sendImage) {
        imagePending = false;
        lastEpoch = imageEpoch;
        lastSentAt = at;
        pp::TileImage im{imageW, imageH, std::move(pendingImage)};
        json h = {{"type", "image"}, {"epoch", imageEpoch}, {"frame", imageFrame}, {"width", imageW}, {"height", imageH},
                  {"assembled_ms", imageAssembledMs}};
        int stride = 1;
        for (const EpochView& e : epochs)
          if (e.epoch == imageEpoch) {
            stride = e.stride;
            h["view_seq"] = e.seq;
            h["interactive"] = e.interactive;
            h["composite"] = e.composite;
            h["preset"] = e.preset;
            if (haveCorners)
              if (const auto o = outlineOnScreen(e.camera, lastCorners))
                h["outline"] = {{(*o)[0][0], (*o)[0][1]}, {(*o)[1][0], (*o)[1][1]}, {(*o)[2][0], (*o)[2][1]},
                                {(*o)[3][0], (*o)[3][1]}};
          }
        h["gap_warning"] = coverage.gapWarning();
        json arr = json::array();
        for (const auto& [f, t] : arrivals)
          if (f <= imageFrame) arr.push_back({f, t});
        h["arrivals"] = arr;
        lock.unlock();
        std::vector<std::uint8_t> rgb = pp::toRgb8(im);
        int jw = im.width, jh = im.height;
        if (stride > 1) {
          // A coarse image (each strided pixel stands for a block): only its
          // strided pixels, which the page scales up to width x height.
          jw = (im.width + stride - 1) / stride;
          jh = (im.height + stride - 1) / stride;
          for (int y = 0; y < jh; ++y)
            for (int x = 0; x < jw; ++x)
              std::memmove(&rgb[(static_cast<std::size_t>(y) * jw + x) * 3],
                          &rgb[(static_cast<std::size_t>(y) * stride * im.width + static_cast<std::size_t>(x) * stride) * 3], 3);
          h["stride"] = stride;
        }
        const std::string jpegBytes = jpeg.encode(rgb.data(), jw, jh, s.jpegQuality);
        h["sent_ms"] = unixMs(std::chrono::system_clock::now());
        std::string msg = pack(h, jpegBytes);
        lock.lock();
        if (!imagePending) pendingImage = std::move(im.rgba);  // reuse the storage
        lastImage = msg;
        server->publish(kImage, std::move(msg));
      }
      if (bmodePending) {
        bmodePending = false;
        const Frame f = std::move(pendingBmode);
        const json h = {{"type", "bmode"}, {"index", bmodeIndex}, {"time_s", bmodeTime}, {"pose_ok", f.imageValid},
                        {"width", f.width}, {"height", f.height}};
        lock.unlock();
        std::vector<std::uint8_t> rgb(static_cast<std::size_t>(f.width) * static_cast<std::size_t>(f.height) * 3);
        for (int y = 0; y < f.height; ++y)
          for (int x = 0; x < f.width; ++x) {
            const auto v = static_cast<std::uint8_t>(std::lround(std::clamp(f.value(x, y), 0.0, 255.0)));
            std::uint8_t* p = &rgb[(static_cast<std::size_t>(y) * static_cast<std::size_t>(f.width) + x) * 3];
            p[0] = p[1] = p[2] = v;
          }
        std::string msg = pack(h, jpeg.encode(rgb.data(), f.width, f.height, s.jpegQuality));
        lock.lock();
        lastBmodeMsg = msg;
        server->publish(kBmode, std::move(msg));
      }
      // The slices, one per pass, so that an image that comes meanwhile waits
      // for one slice at most, not for all three.
      if (sliceAxis == 3 && (volumePending || slicesDirty) && !pendingVolume.bytes.empty()) {
        volumePending = false;
        slicesDirty = false;
        sliceVolume = pendingVolume;  // a copy: the host may hand over the next one meanwhile
        sliceCoverage = coverage;
        for (int a = 0; a < 3; ++a) slicePlanes[a] = planes[a];
        sliceLookNow = sliceLook;
        sliceLookNow.longSide = s.sliceSize;
        sliceWithCoverage = coverageMap;
        sliceAxis = 0;
      }
      if (sliceAxis < 3) {
        const int a = sliceAxis++;
        lock.unlock();
        const SliceImage im = slice(sliceVolume, slicePlanes[a], sliceLookNow, sliceWithCoverage ? &sliceCoverage : nullptr);
        const json h = {{"type", "mpr"},
                        {"axis", a},
                        {"name", sliceName(slicePlanes[a].axis)},
                        {"position", slicePlanes[a].position},
                        {"tilt_deg", slicePlanes[a].tiltDeg},
                        {"window", sliceLookNow.window},
                        {"level", sliceLookNow.level},
                        {"width", im.width},
                        {"height", im.height}};
        std::string msg = pack(h, jpeg.encode(im.rgb.data(), im.width, im.height, s.jpegQuality));
        lock.lock();
        if (sliceAxis == 3) sliceVolume = {};  // the batch is done: no copy kept
        lastSlices[a] = msg;
        server->publish(kSlice0 + a, std::move(msg));
      }
      const auto statsAt = Clock::now();
      if (statsDirty || statsAt - lastStats > std::chrono::milliseconds(500)) {
        statsDirty = false;
        lastStats = statsAt;
        server->publish(kStats, pack(statsJson()));
        server->publish(kState, pack(stateJson()));
      }
    }
  }
};

LiveView::LiveView(const ViewSettings& settings, const Grid& grid, const RenderSettings& base,
                   const gp::ReconSettings& recon, const TransferFunctionSettings& tf, const comm::ControlState& initial,
                   const std::string& recordDir)
    : impl_(std::make_unique<Impl>(settings, grid, base, recon, tf)) {
  checkViewSettings(settings);
  impl_->recordDir = recordDir;
  viewer::ServerOptions o;
  parseListen(settings.listen, o.address, o.port, "view.listen");
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
