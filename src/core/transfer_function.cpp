#include "core/transfer_function.hpp"

#include <algorithm>
#include <limits>

#include "core/config.hpp"
#include "core/error.hpp"

namespace pp5 {

namespace {

// Defaults for the simulated doll in water: the noise floor (about 7) and
// faint speckle stay clear, the vinyl shell (about 150) is nearly opaque and
// skin-coloured, the brightest echoes white.
const std::vector<glm::dvec4> kOpacity = {{0, 0, 0, 0}, {30, 0, 0, 0}, {90, 0.08, 0, 0}, {140, 0.55, 0, 0},
                                          {255, 0.95, 0, 0}};
const std::vector<glm::dvec4> kColour = {{0, 0.0, 0.0, 0.0}, {60, 0.55, 0.3, 0.2}, {150, 1.0, 0.82, 0.68},
                                         {255, 1.0, 1.0, 1.0}};

// Piecewise-linear interpolation of component c of `pts` at x (flat outside).
double lerpPoints(const std::vector<glm::dvec4>& pts, double x, int c) {
  if (x <= pts.front()[0]) return pts.front()[c];
  if (x >= pts.back()[0]) return pts.back()[c];
  for (std::size_t i = 1; i < pts.size(); ++i)
    if (x <= pts[i][0]) {
      const double t = (x - pts[i - 1][0]) / (pts[i][0] - pts[i - 1][0]);
      return pts[i - 1][c] + t * (pts[i][c] - pts[i - 1][c]);
    }
  return pts.back()[c];
}

}  // namespace

std::vector<glm::dvec4> defaultOpacityPoints() { return kOpacity; }
std::vector<glm::dvec4> defaultColourPoints() { return kColour; }

void registerOptions(ConfigSchema& schema, TransferFunctionSettings& s) {
  schema.section("render.tf", "Classification: piecewise-linear transfer functions from grey value to opacity and colour.");
  schema.option("render.tf.opacity", &s.opacity, kOpacity, 2, 0.0, 255.0, true,
                "Opacity points [grey value, alpha]: values 0..255 increasing, alpha 0..1 (per "
                "`render.opacity_unit_mm` of ray). Flat beyond the first and last point.");
  schema.option("render.tf.colour", &s.colour, kColour, 4, 0.0, 255.0, true,
                "Colour points [grey value, red, green, blue]: values 0..255 increasing, components 0..1.");
}

TransferFunction::TransferFunction() : TransferFunction(TransferFunctionSettings{kOpacity, kColour}) {}

TransferFunction::TransferFunction(const TransferFunctionSettings& s) : settings_(s) {
  PP5_CHECK(!s.opacity.empty() && !s.colour.empty());
  for (const auto* pts : {&s.opacity, &s.colour}) {
    for (std::size_t i = 1; i < pts->size(); ++i) PP5_CHECK((*pts)[i][0] > (*pts)[i - 1][0]);
    for (const auto& p : *pts)
      for (int c = 1; c < (pts == &s.opacity ? 2 : 4); ++c) PP5_CHECK(p[c] >= 0.0 && p[c] <= 1.0);
  }
  table_.resize(kTableSize);
  for (int i = 0; i < kTableSize; ++i) {
    const double x = static_cast<double>(i) / kStepsPerLevel;
    table_[static_cast<std::size_t>(i)] = {static_cast<float>(lerpPoints(s.colour, x, 1)),
                                           static_cast<float>(lerpPoints(s.colour, x, 2)),
                                           static_cast<float>(lerpPoints(s.colour, x, 3)),
                                           static_cast<float>(lerpPoints(s.opacity, x, 1))};
  }
  const auto first = std::find_if(table_.begin(), table_.end(), [](const Rgba& e) { return e.a > 0.0f; });
  transparentBelow_ = first == table_.end() ? std::numeric_limits<float>::infinity()
                                            : static_cast<float>(first - table_.begin() - 1);
}

}  // namespace pp5
