#pragma once
// One sample of the global ray lattice, as the ray sampler (GP) produces it
// and the ray-sample cache (PP) stores it. Plain and trivially copyable: it
// travels in MPI messages as is.
#include <cstdint>
#include <type_traits>

namespace pp5 {

struct RaySample {
  std::uint32_t pixel = 0;  // y * image width + x, in the whole image
  std::uint32_t k = 0;      // index along the ray: t_k = t0(pixel) + k * step
  // Premultiplied colour and opacity of the sample, the opacity already
  // corrected for the step (render.opacity_unit_mm).
  float r = 0, g = 0, b = 0, a = 0;
};
static_assert(std::is_trivially_copyable_v<RaySample> && sizeof(RaySample) == 24);

}  // namespace pp5
