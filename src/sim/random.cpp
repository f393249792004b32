#include "sim/random.hpp"

#include <array>

namespace pp5::sim {

namespace {

// Inverse of the standard normal CDF by bisection (only at start-up).
double inverseNormalCdf(double p) {
  double lo = -10.0, hi = 10.0;
  for (int i = 0; i < 100; ++i) {
    const double mid = 0.5 * (lo + hi);
    if (0.5 * std::erfc(-mid / std::sqrt(2.0)) < p)
      lo = mid;
    else
      hi = mid;
  }
  return 0.5 * (lo + hi);
}

struct GaussTable {
  std::array<float, 4096> v{};
  GaussTable() {
    for (std::size_t i = 0; i < v.size(); ++i)
      v[i] = static_cast<float>(inverseNormalCdf((static_cast<double>(i) + 0.5) / static_cast<double>(v.size())));
  }
};

const GaussTable kGauss;

}  // namespace

float gaussianFromBits(std::uint64_t bits) { return kGauss.v[bits & 0xFFFu]; }

}  // namespace pp5::sim
