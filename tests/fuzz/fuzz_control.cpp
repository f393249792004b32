// libFuzzer target: the live viewer's control messages (docs/protocol.md), as
// the server's thread hands them to LiveView::control. Every message gets
// either "" (applied) or an error text; nothing else may happen, and the
// wanted state must stay within what the pipeline accepts. The corpus is the
// messages the page sends (written by this target with PP5_FUZZ_SEEDS_DIR set).
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <unistd.h>

#include "comm/messages.hpp"
#include "core/render_settings.hpp"
#include "core/transfer_function.hpp"
#include "reconstruction/reconstruction.hpp"
#include "rendering/shading.hpp"
#include "outputs/live_view.hpp"
#include "pipeline/parallel_settings.hpp"
#include "fuzz_util.hpp"

namespace {

const char* kSeeds[] = {
    R"({"type": "view", "seq": 4, "azimuth": 10, "elevation": 5, "distance": 2.5, "pan": [0.1, -0.2], "interactive": true})",
    R"({"type": "view", "seq": 5, "azimuth": -170, "elevation": -60, "distance": 4, "pan": [0, 0], "interactive": false})",
    R"({"type": "composite", "mode": "mip"})",
    R"({"type": "composite", "mode": "over"})",
    R"({"type": "tf", "level": 100, "window": 60, "opacity": 0.5})",
    R"({"type": "tf", "preset": "soft tissue"})",
    R"({"type": "shading", "mode": "phong", "light": "headlight", "light_azimuth": 30, "light_elevation": 10})",
    R"({"type": "value_window", "window": 200, "level": 100})",
    R"({"type": "mpr", "axis": "axial", "position": 0.5})",
    R"({"type": "mpr", "axis": 2, "position": 0.25})",
    R"({"type": "mpr_window", "window": 255, "level": 128})",
    R"({"type": "mpr_tilt", "degrees": 10})",
    R"({"type": "coverage_map", "on": true})",
    R"({"type": "pause"})",
    R"({"type": "resume"})",
    R"({"type": "record", "on": false})",
};

pp5::host::LiveView& viewer() {
  static std::unique_ptr<pp5::host::LiveView> live = [] {
    pp5::Grid g;
    g.dims = pp5::Index3(24, 20, 16);
    g.spacing = pp5::Vec3(1.0);
    pp5::RenderSettings render;
    render.width = render.height = 32;
    pp5::TransferFunctionSettings tf;
    const auto initial = pp5::parallel::makeControlState(render, pp5::gp::ShadeSettings{}, tf);
    pp5::host::ViewSettings vs;
    vs.listen = "127.0.0.1:0";
    const auto dir = std::filesystem::temp_directory_path() / ("pp5fuzz-control-" + std::to_string(getpid()));
    std::filesystem::create_directories(dir);
    return std::make_unique<pp5::host::LiveView>(vs, g, render, pp5::gp::ReconSettings{}, tf, initial, dir.string());
  }();
  return *live;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  pp5::fuzz::writeSeedsIfAsked([](const std::string& dir) {
    int i = 0;
    for (const char* s : kSeeds) std::ofstream(dir + "/seed-" + std::to_string(i++)) << s;
  });
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string msg(reinterpret_cast<const char*>(data), size);
  const std::string err = viewer().control(msg);
  if (err.empty()) {
    // Applied: the state the pipeline will get must be one it can use.
    const pp5::comm::ControlState c = viewer().wanted().state;
    if (!std::isfinite(c.azimuthDeg) || !std::isfinite(c.elevationDeg) || !std::isfinite(c.distance)) std::abort();
  }
  return 0;
}
