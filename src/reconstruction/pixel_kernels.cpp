#include "reconstruction/pixel_kernels.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.hpp"
#include "core/simd.hpp"

namespace pp5::gp::pixel {

namespace {

#include "reconstruction/pixel_walk.inl"
#include "reconstruction/pixel_nearest.inl"
#include "reconstruction/pixel_trilinear.inl"

}  // namespace

void splatPlus(Method method, Compounding comp, const Job& job, PlusCell* c, const Slab& slab, bool split,
               SlabOut& so) {
  if (method == Method::Nearest) {
    switch (comp) {
      case Compounding::Mean: nearestPlus<Compounding::Mean>(job, c, slab, split, so); break;
      case Compounding::Latest: nearestPlus<Compounding::Latest>(job, c, slab, split, so); break;
      case Compounding::Maximum: nearestPlus<Compounding::Maximum>(job, c, slab, split, so); break;
    }
  } else {
    switch (comp) {
      case Compounding::Mean: trilinearPlus<Compounding::Mean>(job, c, slab, split, so); break;
      case Compounding::Latest: trilinearPlus<Compounding::Latest>(job, c, slab, split, so); break;
      case Compounding::Maximum: trilinearPlus<Compounding::Maximum>(job, c, slab, split, so); break;
    }
  }
}

void splatFloat(Method method, Compounding comp, const Job& job, FloatCell* c, const Slab& slab, bool split,
                SlabOut& so) {
  auto run = [&]<class Pix>() {
    if (method == Method::Nearest) {
      switch (comp) {
        case Compounding::Mean: nearestFloat<Pix, Compounding::Mean>(job, c, slab, split, so); break;
        case Compounding::Latest: nearestFloat<Pix, Compounding::Latest>(job, c, slab, split, so); break;
        case Compounding::Maximum: nearestFloat<Pix, Compounding::Maximum>(job, c, slab, split, so); break;
      }
    } else {
      switch (comp) {
        case Compounding::Mean: trilinearFloat<Pix, Compounding::Mean>(job, c, slab, split, so); break;
        case Compounding::Latest: trilinearFloat<Pix, Compounding::Latest>(job, c, slab, split, so); break;
        case Compounding::Maximum: trilinearFloat<Pix, Compounding::Maximum>(job, c, slab, split, so); break;
      }
    }
  };
  if (job.u16)
    run.template operator()<std::uint16_t>();
  else
    run.template operator()<std::uint8_t>();
}

}  // namespace pp5::gp::pixel
