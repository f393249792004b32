#pragma once
// A volume read from a file (one that pp5echo or PLUS wrote) in place of a
// reconstruction, so that the renderer and the live viewer show it like a
// volume they built (`pp5echo view VOLUME.mha`). It takes no frames.
#include <memory>

#include "reconstruction/reconstruction.hpp"

namespace pp5::gp {

// The values are kept as F32 grey levels; every voxel counts as covered.
std::unique_ptr<Reconstructor> storedVolume(const Volume& v);

}  // namespace pp5::gp
