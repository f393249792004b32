#pragma once
// Classification by table lookup: a reconstructed grey value (0..255) to
// colour and opacity, by piecewise-linear transfer functions from the
// configuration ([render.tf]). Never a threshold: a value between two points
// gets the linear blend of theirs, so classification is continuous.
#include <array>
#include <vector>

#include <glm/glm.hpp>

namespace pp5 {

class ConfigSchema;

// Colour and opacity, each 0..1 (straight, not premultiplied, unless stated).
struct Rgba {
  float r = 0, g = 0, b = 0, a = 0;
  bool operator==(const Rgba&) const = default;
};

// The [render.tf] defaults.
std::vector<glm::dvec4> defaultOpacityPoints();
std::vector<glm::dvec4> defaultColourPoints();

struct TransferFunctionSettings {
  // Opacity points (value, alpha) and colour points (value, r, g, b); values
  // 0..255 increasing, components 0..1. Stored as dvec4 (unused components 0).
  std::vector<glm::dvec4> opacity = defaultOpacityPoints();
  std::vector<glm::dvec4> colour = defaultColourPoints();
};
void registerOptions(ConfigSchema& schema, TransferFunctionSettings& s);

class TransferFunction {
public:
  static constexpr int kStepsPerLevel = 16;  // table resolution: 1/16 grey level
  static constexpr int kTableSize = 255 * kStepsPerLevel + 1;

  TransferFunction();  // the [render.tf] defaults
  // Points as in TransferFunctionSettings; InvariantError if empty or not increasing.
  explicit TransferFunction(const TransferFunctionSettings& s);

  // The classification of `value` (clamped to 0..255): the two table entries
  // around it, blended linearly. Exact (to float) wherever the points' values
  // are multiples of 1/16 grey level, and continuous everywhere.
  Rgba operator()(float value) const {
    const float x = value <= 0.0f ? 0.0f : value >= 255.0f ? 255.0f : value;
    const float t = x * static_cast<float>(kStepsPerLevel);
    const int i = static_cast<int>(t);
    if (i >= kTableSize - 1) return table_[kTableSize - 1];
    const float f = t - static_cast<float>(i);
    const Rgba& a = table_[static_cast<std::size_t>(i)];
    const Rgba& b = table_[static_cast<std::size_t>(i) + 1];
    return {a.r + f * (b.r - a.r), a.g + f * (b.g - a.g), a.b + f * (b.b - a.b), a.a + f * (b.a - a.a)};
  }
  const TransferFunctionSettings& settings() const { return settings_; }
  // True when every value up to `value` classifies to opacity exactly 0
  // (both table entries around it are 0): a run of water below the opacity
  // ramp needs no lookup.
  bool transparentUpTo(float value) const {
    const float x = value <= 0.0f ? 0.0f : value >= 255.0f ? 255.0f : value;
    return x * static_cast<float>(kStepsPerLevel) < transparentBelow_;
  }
  // The bound transparentUpTo compares with, for code that tests many values
  // at once by the same operations.
  float transparentBelow() const { return transparentBelow_; }

private:
  TransferFunctionSettings settings_;
  std::vector<Rgba> table_;
  // operator() blends entries int(t) and int(t) + 1 (t = value * steps):
  // below the index before the first entry with opacity > 0, both are 0.
  float transparentBelow_ = 0.0f;
};

}  // namespace pp5
