// The live viewer's encoder thread: the newest image, B-mode frame, slices,
// state and figures, each turned into a message for the browsers.
#include "outputs/live_view_impl.hpp"

namespace pp5::host {

using namespace live;

json LiveView::Impl::stateJson() const {
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

json LiveView::Impl::statsJson() const {
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

void LiveView::Impl::run() {
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
}  // namespace pp5::host
