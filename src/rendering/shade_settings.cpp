// [render.shading]: the options, and the ranges every value is held to.
#include <cmath>

#include <fmt/format.h>

#include "core/config.hpp"
#include "core/error.hpp"
#include "rendering/shading.hpp"

namespace pp5::gp {


namespace {

// One range per numeric option, shared by the schema (for files) and by
// shade() (for settings built in code), so that no value the schema would
// refuse reaches the voxel loop, where a shininess of 0 or a NaN would.
struct Range {
  double lo, hi;
};
constexpr Range kCoefficient{0.0, 1.0}, kShininess{1.0, 256.0}, kFlatGradient{0.001, 1000.0},
    kOpacityLow{0.0, 10000.0}, kOpacityWidth{0.001, 10000.0};

}  // namespace

void checkShadeSettings(const ShadeSettings& s) {
  auto check = [](const char* key, double v, Range r) {
    if (!(v >= r.lo && v <= r.hi))
      throw InputError(fmt::format("render.shading.{} = {} is out of range {} .. {}", key, v, r.lo, r.hi));
  };
  check("ambient", s.ambient, kCoefficient);
  check("diffuse", s.diffuse, kCoefficient);
  check("specular", s.specular, kCoefficient);
  check("shininess", s.shininess, kShininess);
  check("flat_gradient", s.flatGradient, kFlatGradient);
  check("gradient_opacity_low", s.gradientOpacityLow, kOpacityLow);
  check("gradient_opacity_width", s.gradientOpacityWidth, kOpacityWidth);
  const double len = glm::length(s.lightDirection);
  if (s.light == LightKind::Direction && (!(len > 1e-9) || !std::isfinite(len)))
    throw InputError(fmt::format("render.shading.light_direction = [{}, {}, {}] has no direction",
                                 s.lightDirection.x, s.lightDirection.y, s.lightDirection.z));
}

void registerOptions(ConfigSchema& c, ShadeSettings& s) {
  const ShadeSettings d;
  c.section("render.shading",
            "Shading: each voxel's colour and opacity from its grey value through the transfer function "
            "([render.tf]), lit in `phong` mode, stored premultiplied for the ray sampler.");
  enumOption(c, "render.shading.mode", &s.mode, d.mode,
           "`phong`: the transfer function's colour lit by the grey-value gradient (two-sided Phong); "
           "`value`: the transfer function's colour and opacity unlit; `grey`: the voxel's own grey level as its "
           "colour (the image value) with the transfer function's opacity, unlit.");
  c.option("render.shading.ambient", &s.ambient, d.ambient, kCoefficient.lo, kCoefficient.hi,
           "Phong: ambient coefficient.");
  c.option("render.shading.diffuse", &s.diffuse, d.diffuse, kCoefficient.lo, kCoefficient.hi,
           "Phong: diffuse coefficient, times abs(N.L) (two-sided). With ambient + diffuse = 1, a surface facing "
           "the light and a flat region keep the transfer function's colour.");
  c.option("render.shading.specular", &s.specular, d.specular, kCoefficient.lo, kCoefficient.hi,
           "Phong: coefficient of the white highlight, times max(0, N.H)^shininess with N turned towards "
           "the light.");
  c.option("render.shading.shininess", &s.shininess, d.shininess, kShininess.lo, kShininess.hi,
           "Phong: specular exponent.");
  enumOption(c, "render.shading.light", &s.light, d.light,
           "`viewer`: a light at the eye (perspective: from each voxel towards the eye; orthographic: against "
           "the view direction); `direction`: a distant light along `render.shading.light_direction`.");
  c.option("render.shading.light_direction", &s.lightDirection, d.lightDirection, -1.0, 1.0,
           "Direction of the distant light in world coordinates, from the light towards the scene; any "
           "non-zero vector (it is normalised).");
  c.option("render.shading.flat_gradient", &s.flatGradient, d.flatGradient, kFlatGradient.lo, kFlatGradient.hi,
           "Gradient magnitude, grey levels per mm, below which a normal fades out: a voxel whose gradient is "
           "g < flat_gradient is lit as w Phong + (1 - w) (ambient + diffuse), w = g / flat_gradient.");
  c.option("render.shading.gradient_opacity", &s.gradientOpacity, d.gradientOpacity,
           "Multiply each voxel's opacity by a ramp of its gradient magnitude (Levoy 1988), so boundaries "
           "show and homogeneous regions fade.");
  c.option("render.shading.gradient_opacity_low", &s.gradientOpacityLow, d.gradientOpacityLow, kOpacityLow.lo,
           kOpacityLow.hi, "Gradient opacity: the ramp is 0 up to this gradient magnitude, grey levels per mm.");
  c.option("render.shading.gradient_opacity_width", &s.gradientOpacityWidth, d.gradientOpacityWidth,
           kOpacityWidth.lo, kOpacityWidth.hi,
           "Gradient opacity: the ramp rises linearly to 1 over this many grey levels per mm above the low end.");
}

}  // namespace pp5::gp
