#include "reconstruction/hole_fill.hpp"

#include <algorithm>
#include <numbers>
#include <string>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::gp {

namespace {

std::string name(PlusHoleFillingType t) { return std::string(toPlusString(t)); }

}  // namespace

HoleFiller::HoleFiller(const std::vector<PlusHoleFillingElement>& elements, bool plusArithmetic)
    : plus_(plusArithmetic) {
  for (const PlusHoleFillingElement& e : elements) {
    Element el;
    el.e = e;
    if (e.type == PlusHoleFillingType::Stick) {
      if (e.stickLengthLimit < 1 || e.numberOfSticksToUse < 1)
        throw InputError(fmt::format("hole filling element STICK: StickLengthLimit ({}) and NumberOfSticksToUse ({}) "
                                     "must be at least 1",
                                     e.stickLengthLimit, e.numberOfSticksToUse));
      reach_ = std::max(reach_, e.stickLengthLimit - 1);
      elements_.push_back(std::move(el));
      continue;
    }
    if (e.size < 1)
      throw InputError(fmt::format("hole filling element {}: Size ({}) must be at least 1", name(e.type), e.size));
    el.half = (e.size - 1) / 2;
    reach_ = std::max(reach_, el.half);
    const bool gaussian =
        e.type == PlusHoleFillingType::Gaussian || e.type == PlusHoleFillingType::GaussianAccumulation;
    if (gaussian && !(e.stdev > 0.0))
      throw InputError(fmt::format("hole filling element {}: Stdev ({}) must be positive", name(e.type), e.stdev));
    if (e.type != PlusHoleFillingType::NearestNeighbor) {
      const int S = e.size;
      const double c = (S - 1) / 2.0;  // the cube's centre, as an offset from its corner
      const double norm = std::pow(2.0 * std::numbers::pi, 1.5) * e.stdev * e.stdev * e.stdev;
      el.kernel.resize(static_cast<std::size_t>(S) * S * S);
      for (int z = 0; z < S; ++z)
        for (int y = 0; y < S; ++y)
          for (int x = 0; x < S; ++x) {
            const double d2 = (x - c) * (x - c) + (y - c) * (y - c) + (z - c) * (z - c);
            double k;
            if (gaussian)
              k = std::exp(-d2 / (2.0 * e.stdev * e.stdev)) / norm;
            else
              k = d2 > 0.0 ? 1.0 / std::sqrt(d2) : 0.0;
            el.kernel[static_cast<std::size_t>((z * S + y) * S + x)] = static_cast<float>(k);
          }
    }
    elements_.push_back(std::move(el));
  }
}

std::vector<PlusHoleFillingElement> HoleFiller::defaultElements() {
  PlusHoleFillingElement e;
  e.type = PlusHoleFillingType::Stick;
  e.stickLengthLimit = 9;
  e.numberOfSticksToUse = 1;
  return {e};
}

namespace {

struct VolumeSource {
  const float* v;
  const float* w;
  bool known(std::size_t i) const { return w[i] != 0.0f; }
  float value(std::size_t i) const { return v[i]; }
  float weight(std::size_t i) const { return w[i]; }
};

}  // namespace

Volume fillHoles(const Volume& unfilled, const Volume& weights, const std::vector<PlusHoleFillingElement>& elements,
                 bool plusArithmetic) {
  PP5_CHECK(unfilled.type == ScalarType::F32);
  PP5_CHECK(weights.type == ScalarType::F32);
  PP5_CHECK(unfilled.grid.dims == weights.grid.dims);
  const HoleFiller filler(elements, plusArithmetic);
  Volume out = unfilled;
  const Index3 d = unfilled.grid.dims;
  const VolumeSource src{reinterpret_cast<const float*>(unfilled.bytes.data()),
                         reinterpret_cast<const float*>(weights.bytes.data())};
  float* o = reinterpret_cast<float*>(out.bytes.data());
  for (std::int64_t z = 0; z < d.z; ++z)
    for (std::int64_t y = 0; y < d.y; ++y)
      for (std::int64_t x = 0; x < d.x; ++x) {
        const std::size_t i = holefill_detail::lin(d, x, y, z);
        if (!src.known(i)) o[i] = filler.fill(src, d, x, y, z);
      }
  return out;
}

}  // namespace pp5::gp
