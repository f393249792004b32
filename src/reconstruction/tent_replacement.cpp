// The tent reconstructor's replacement of aging data (the notes above
// TentReconstructor in reconstruction/tent_reconstructor.hpp): the contributions stored
// for motion vectors applied once the cells to rebase are known, and the
// rebasing itself. The decay and the motion-vector value are part of the
// voxel update (TentReconstructor::applyVoxel).
#include <limits>

#include "reconstruction/tent_reconstructor.hpp"

namespace pp5::gp::tent {

void TentReconstructor::applyStored(float tf) {
  forRows([&](std::size_t first, std::size_t end) {
    float* const acc = acc_.data();
    float* const out = outF32();
    float cacheT = std::numeric_limits<float>::quiet_NaN(), cacheF = 1.0f;
    for (std::size_t r = first; r < end; ++r) {
      const Row& row = rows_[r];
      const std::size_t lin0 = grid_.linear(0, row.j, row.k);
      ChangedRange changed;
      for (std::int64_t i = row.i0; i <= row.i1; ++i) {
        const float* c = contrib_.data() + 2 * (row.offset + static_cast<std::size_t>(i - row.i0));
        if (c[0] > 0.0f && applyVoxel<Replacement::MotionVector>(acc, out, lin0 + static_cast<std::size_t>(i), c[0],
                                                                  c[1], tf, cacheT, cacheF))
          changed.add(i, out[lin0 + static_cast<std::size_t>(i)]);
      }
      rowChanged_[r] = changed;
    }
  });
}

// Motion vectors: finds the cells that get data from the current slice (its
// contributions are in contrib_), rebases those whose direction opposes the
// slice's, and records the slice's direction in them.
void TentReconstructor::rebaseCells(const Vec3& dir) {
  if (++sliceCounter_ == 0) {  // the stamps wrapped: start over
    std::fill(cellStamp_.begin(), cellStamp_.end(), 0u);
    sliceCounter_ = 1;
  }
  const std::int64_t B = settings_.tent.motionVectorBrick;
  touched_.clear();
  for (const Row& row : rows_) {
    const std::int64_t cj = row.j / B, ck = row.k / B;
    for (std::int64_t i = row.i0; i <= row.i1; ++i) {
      if (!(contrib_[2 * (row.offset + static_cast<std::size_t>(i - row.i0))] > 0.0f)) continue;
      const auto cell = static_cast<std::uint32_t>((ck * cellDims_.y + cj) * cellDims_.x + i / B);
      if (cellStamp_[cell] != sliceCounter_) {
        cellStamp_[cell] = sliceCounter_;
        touched_.push_back(cell);
      }
    }
  }
  if (dir == Vec3(0.0)) return;  // no direction yet: accumulate, remember nothing
  const glm::vec3 d(dir);
  for (const std::uint32_t cell : touched_) {
    glm::vec3& cd = cellDir_[cell];
    if (glm::dot(cd, d) < 0.0f) {
      const std::int64_t c = cell;
      const Index3 ci(c % cellDims_.x, (c / cellDims_.x) % cellDims_.y, c / (cellDims_.x * cellDims_.y));
      const Index3 lo = ci * Index3(B), hi = glm::min(lo + Index3(B), grid_.dims);
      for (std::int64_t k = lo.z; k < hi.z; ++k)
        for (std::int64_t j = lo.y; j < hi.y; ++j)
          for (std::int64_t i = lo.x; i < hi.x; ++i) {
            const std::size_t v = grid_.linear(i, j, k);
            if (!(acc_[2 * v + 1] > 0.0f)) continue;  // nothing new since the last rebase
            const float bv = outputAt(v), bw = weightAt(v);
            baseV_[v] = bv;
            baseW_[v] = bw;
            acc_[2 * v + 1] = 0.0f;
            acc_[2 * v] = 0.0f;
          }
    }
    cd = d;
  }
}

}  // namespace pp5::gp::tent
