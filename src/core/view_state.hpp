#pragma once
// What the user steers while a run goes on: the view, the shading, the
// transfer function and the live composition mode, whole, so that whoever
// applies it needs no history. A plain, trivially copyable struct: a control
// change carries it as it is (comm::ControlMsg), and the run loop, the viewer
// and run.script speak of it (host::ViewState).
#include <cstdint>
#include <type_traits>

namespace pp5 {

struct ViewState {
  // View (render.*)
  std::uint8_t projection = 0;  // 0 perspective, 1 orthographic
  std::uint8_t liveMode = 0;    // pp::CompositeMode of the live image
  std::uint8_t shadeMode = 0;   // gp::ShadeMode
  std::uint8_t light = 0;       // gp::LightKind
  std::uint8_t gradientOpacity = 0;
  std::uint8_t orbitValid = 0;  // 1: eye given by orbit below instead of the settings' azimuth/elevation
  std::uint8_t pixelStride = 1;  // the viewer's drag: rays for every n-th pixel along x and y (render.pixel_stride)
  std::uint8_t pad[1] = {};
  double fovDeg = 30.0, azimuthDeg = 0.0, elevationDeg = 0.0, distance = 3.0;
  // An orbit of the settings' camera (the rotating loop): axis and degrees.
  double orbitAxis[3] = {0, 0, 1};
  double orbitDeg = 0.0;
  // The viewer's drag (render.step_scale, render.pan_mm; not options).
  double stepScale = 1.0;
  double panMm[2] = {0.0, 0.0};
  double valueWindow[2] = {0.0, 255.0};  // render.value_window
  // Shading (render.shading.*)
  double ambient = 0, diffuse = 0, specular = 0, shininess = 0;
  double lightDirection[3] = {};
  double flatGradient = 0, gradientOpacityLow = 0, gradientOpacityWidth = 0;
  // Transfer function (render.tf.*): points as (value, alpha) and (value, r, g, b).
  static constexpr int kMaxPoints = 32;
  std::int32_t opacityPoints = 0, colourPoints = 0;
  double opacity[kMaxPoints][2] = {};
  double colour[kMaxPoints][4] = {};
};
static_assert(std::is_trivially_copyable_v<ViewState>);

}  // namespace pp5
