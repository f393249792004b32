// The live viewer's control messages, as the page sends them (on the
// server's thread): checked field by field, then handed to the pipeline as
// the state it wants.
#include "outputs/live_view_impl.hpp"

namespace pp5::host {

using namespace live;

namespace {

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


}  // namespace

std::string LiveView::Impl::control(const std::string& textIn) {
  const std::lock_guard lock(m);
  const auto now = Clock::now();  // (each client's rate is bounded by the server, viewer_server.hpp)
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

void LiveView::Impl::setTf(comm::ControlState& c, const TransferFunctionSettings& tf) {
  c.opacityPoints = static_cast<std::int32_t>(std::min<std::size_t>(tf.opacity.size(), comm::ControlState::kMaxPoints));
  for (int i = 0; i < c.opacityPoints; ++i) {
    c.opacity[i][0] = tf.opacity[static_cast<std::size_t>(i)].x;
    c.opacity[i][1] = tf.opacity[static_cast<std::size_t>(i)].y;
  }
}

}  // namespace pp5::host
