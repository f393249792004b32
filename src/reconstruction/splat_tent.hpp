#pragma once
// The 1990 paper's reconstruction (Ohbuchi & Fuchs): forward mapping with an
// asymmetric tent kernel that rotates with the slice, a 3D weight buffer,
// adaptive inter-slice fill-in, and replacement of aging data.
#include <memory>

#include "reconstruction/reconstruction.hpp"

namespace pp5::gp {

std::uint64_t tentBytesPerVoxel(const ReconSettings& s);
std::unique_ptr<Reconstructor> makeTentReconstructor(const Grid& g, const ReconSettings& s);

}  // namespace pp5::gp
