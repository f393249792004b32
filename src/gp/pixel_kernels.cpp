#include "gp/pixel_kernels.hpp"

#include "gp/pixel_methods.hpp"

namespace pp5::gp::pixel {

void splatPlus(Method method, Compounding comp, const Job& job, PlusCell* c, const Slab& slab, bool split,
               SlabOut& so) {
  if (method == Method::Nearest) walk::nearestPlus(comp, job, c, slab, split, so);
  else walk::trilinearPlus(comp, job, c, slab, split, so);
}

void splatFloat(Method method, Compounding comp, const Job& job, FloatCell* c, const Slab& slab, bool split,
                SlabOut& so) {
  if (method == Method::Nearest) walk::nearestFloat(comp, job, c, slab, split, so);
  else walk::trilinearFloat(comp, job, c, slab, split, so);
}

}  // namespace pp5::gp::pixel
