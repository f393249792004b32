#pragma once
// The pixel methods' entries, one file each (gp/pixel_nearest.cpp,
// gp/pixel_trilinear.cpp), which gp/pixel_kernels.cpp dispatches to. Not for
// other files.
#include "gp/pixel_kernels.hpp"

namespace pp5::gp::pixel::walk {

// Each method's splatting for every compounding (and, in float, both pixel types).
void nearestPlus(Compounding comp, const Job& job, PlusCell* c, const Slab& slab, bool split, SlabOut& so);
void nearestFloat(Compounding comp, const Job& job, FloatCell* c, const Slab& slab, bool split, SlabOut& so);
void trilinearPlus(Compounding comp, const Job& job, PlusCell* c, const Slab& slab, bool split, SlabOut& so);
void trilinearFloat(Compounding comp, const Job& job, FloatCell* c, const Slab& slab, bool split, SlabOut& so);

}  // namespace pp5::gp::pixel::walk
