#pragma once
// The live viewer's inside (outputs/live_view.hpp), shared by its three files:
// live_view.cpp (the public calls, from the pipeline's thread),
// live_view_control.cpp (the page's control messages, on the server's
// thread) and live_view_encoder.cpp (the encoder's thread: JPEGs, slices and
// figures to the browsers). Not for other folders.
#include "outputs/live_view.hpp"
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

namespace pp5::host {

namespace live {

using json = nlohmann::json;
using Clock = std::chrono::steady_clock;


inline std::int64_t unixMs(std::chrono::system_clock::time_point t) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(t.time_since_epoch()).count();
}

// One message: a little-endian u32 header length, the JSON header, the payload.
inline std::string pack(const json& header, const std::string& payload = {}) {
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

inline std::vector<double> opacityOf(const comm::ControlState& c) {
  const int n = std::clamp(c.opacityPoints, 0, comm::ControlState::kMaxPoints);
  return {&c.opacity[0][0], &c.opacity[0][0] + 2 * n};
}

}  // namespace live

struct LiveView::Impl {
  using json = live::json;
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

  std::string control(const std::string& textIn);
  static void setTf(comm::ControlState& c, const TransferFunctionSettings& tf);
  json stateJson() const;
  json statsJson() const;
  void run();
};

}  // namespace pp5::host
