#include "gp/empty_space.hpp"

#include <algorithm>
#include <bit>
#include <cstring>

#include <omp.h>

#include "core/error.hpp"
#include "core/threads.hpp"

namespace pp5::gp {

EmptySpaceMap::EmptySpaceMap(const ShadeBuffer& shade, int threads) : grid_(shade.grid()) {
  const Index3& d = grid_.dims;
  PP5_CHECK_GE(d.x, 2);
  PP5_CHECK_GE(d.y, 2);
  PP5_CHECK_GE(d.z, 2);
  bdims_ = (cellDims() + Index3(kBrickCells - 1)) / Index3(kBrickCells);
  const std::size_t n = static_cast<std::size_t>(bdims_.x * bdims_.y * bdims_.z);
  occupied_.assign(n, 0);
  dist_.assign(n, 0);
  const std::int64_t slices = bdims_.z * bdims_.y;
#pragma omp parallel for num_threads(resolveThreads(threads)) schedule(dynamic, 1)
  for (std::int64_t s = 0; s < slices; ++s)
    for (std::int64_t bi = 0; bi < bdims_.x; ++bi) scanBrick(shade, bi, s % bdims_.y, s / bdims_.y);
  computeDistances();
}

void EmptySpaceMap::scanBrick(const ShadeBuffer& shade, std::int64_t bi, std::int64_t bj, std::int64_t bk) {
  // The brick's cells read voxels [lo, lo + kBrickCells] inclusive.
  const Index3 lo = Index3(bi, bj, bk) * Index3(kBrickCells);
  const Index3 hi = glm::min(lo + Index3(kBrickCells + 1), grid_.dims);
  occupied_[static_cast<std::size_t>((bk * bdims_.y + bj) * bdims_.x + bi)] = anyVisible(shade, {lo, hi}) ? 1 : 0;
}

bool EmptySpaceMap::anyVisible(const ShadeBuffer& shade, const Box3& b) const {
  // OR whole voxels as 32-bit words and keep alpha, the high byte (r, g, b,
  // a in memory, little-endian); a full brick's rows (9 voxels) with a fixed
  // count the compiler unrolls.
  static_assert(std::endian::native == std::endian::little);
  const ShadeVoxel* v = shade.data();
  const std::int64_t n = b.hi.x - b.lo.x;
  if (n <= 0) return false;
  auto orRow = [](const ShadeVoxel* row, std::int64_t count) {
    std::uint32_t acc = 0;
    for (std::int64_t x = 0; x < count; ++x) {
      std::uint32_t w;
      std::memcpy(&w, row + x, sizeof w);
      acc |= w;
    }
    return acc;
  };
  std::uint32_t any = 0;
  for (std::int64_t z = b.lo.z; z < b.hi.z && !any; ++z)
    for (std::int64_t y = b.lo.y; y < b.hi.y; ++y) {
      const ShadeVoxel* row = v + grid_.linear(b.lo.x, y, z);
      any |= (n == kBrickCells + 1 ? orRow(row, kBrickCells + 1) : orRow(row, n)) >> 24;
    }
  return any != 0;
}

void EmptySpaceMap::update(const ShadeBuffer& shade, std::span<const Box3> changed) {
  checkSameGrid(shade.grid(), grid_);
  std::vector<std::uint8_t> seen(occupied_.size(), 0);
  std::vector<Box3> inGrid;
  for (const Box3& b0 : changed) {
    const Box3 b = b0.intersect({Index3(0), grid_.dims});
    if (!b.empty()) inGrid.push_back(b);
  }
  bool any = false;
  for (const Box3& b : inGrid) {
    // Voxel v is read by cells v - 1 and v.
    const Index3 clo = glm::max(b.lo - Index3(1), Index3(0)) / Index3(kBrickCells);
    const Index3 chi = glm::min((b.hi - Index3(1)) / Index3(kBrickCells), bdims_ - Index3(1));
    for (std::int64_t k = clo.z; k <= chi.z; ++k)
      for (std::int64_t j = clo.y; j <= chi.y; ++j)
        for (std::int64_t i = clo.x; i <= chi.x; ++i) {
          const auto id = static_cast<std::size_t>((k * bdims_.y + j) * bdims_.x + i);
          if (seen[id]) continue;
          seen[id] = 1;
          any = true;
          if (occupied_[id]) {
            scanBrick(shade, i, j, k);
            continue;
          }
          // Empty before: every voxel it reads was transparent, and only the
          // changed boxes were re-shaded, so only their part can be visible now.
          const Index3 lo = Index3(i, j, k) * Index3(kBrickCells);
          const Box3 reads{lo, glm::min(lo + Index3(kBrickCells + 1), grid_.dims)};
          bool visible = false;
          for (const Box3& c : inGrid) {
            visible = anyVisible(shade, reads.intersect(c));
            if (visible) break;
          }
          occupied_[id] = visible ? 1 : 0;
        }
  }
  if (any) computeDistances();
}

void EmptySpaceMap::computeDistances() {
  // Two raster passes with the full 26-neighbour mask give the exact
  // chessboard distance. The map is padded by one brick of "infinity" on
  // every side, so no neighbour needs a bounds check. In each pass a row
  // first takes the 12 neighbours of the rows already done (independent
  // along x, so vectorised), then the one before it in the same row, in order.
  const std::int64_t X = bdims_.x, Y = bdims_.y, Z = bdims_.z;
  const std::int64_t PX = X + 2, PY = Y + 2, PZ = Z + 2;
  constexpr std::uint16_t kInf = 0x7fff;  // + 1 cannot overflow, and stays above every distance
  std::vector<std::uint16_t> pad(static_cast<std::size_t>(PX * PY * PZ), kInf);
  auto at = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
    return static_cast<std::size_t>((z * PY + y) * PX + x);
  };
  for (std::int64_t z = 0; z < Z; ++z)
    for (std::int64_t y = 0; y < Y; ++y)
      for (std::int64_t x = 0; x < X; ++x)
        if (occupied_[static_cast<std::size_t>((z * Y + y) * X + x)]) pad[at(x + 1, y + 1, z + 1)] = 0;
  std::vector<std::uint16_t> t(static_cast<std::size_t>(PX));
  auto pass = [&](int sign) {
    // The 12 earlier neighbours' offsets: the previous row of this plane and
    // the previous plane's 3x3 rows, in this pass's direction.
    std::int64_t off[12];
    int n = 0;
    for (int dx = -1; dx <= 1; ++dx) off[n++] = sign * (-PX + dx);
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) off[n++] = sign * (-PX * PY + dy * PX + dx);
    for (std::int64_t zz = 0; zz < Z; ++zz)
      for (std::int64_t yy = 0; yy < Y; ++yy) {
        const std::int64_t z = sign > 0 ? zz + 1 : Z - zz, y = sign > 0 ? yy + 1 : Y - yy;
        std::uint16_t* row = pad.data() + at(0, y, z);
        for (std::int64_t x = 1; x <= X; ++x) {
          std::uint16_t m = row[x + off[0]];
          for (int q = 1; q < 12; ++q) m = std::min(m, row[x + off[q]]);
          t[static_cast<std::size_t>(x)] = std::min<std::uint16_t>(row[x], static_cast<std::uint16_t>(m + 1));
        }
        if (sign > 0)
          for (std::int64_t x = 1; x <= X; ++x)
            row[x] = std::min<std::uint16_t>(t[static_cast<std::size_t>(x)], static_cast<std::uint16_t>(row[x - 1] + 1));
        else
          for (std::int64_t x = X; x >= 1; --x)
            row[x] = std::min<std::uint16_t>(t[static_cast<std::size_t>(x)], static_cast<std::uint16_t>(row[x + 1] + 1));
      }
  };
  pass(1);
  pass(-1);
  auto idx = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
    return static_cast<std::size_t>((z * Y + y) * X + x);
  };
  for (std::int64_t z = 0; z < Z; ++z)
    for (std::int64_t y = 0; y < Y; ++y)
      for (std::int64_t x = 0; x < X; ++x)
        dist_[idx(x, y, z)] = static_cast<std::uint8_t>(std::min<std::uint16_t>(pad[at(x + 1, y + 1, z + 1)], 255));
  Box3 b{bdims_, Index3(0)};
  for (std::int64_t z = 0; z < Z; ++z)
    for (std::int64_t y = 0; y < Y; ++y)
      for (std::int64_t x = 0; x < X; ++x)
        if (occupied_[idx(x, y, z)]) {
          b.lo = glm::min(b.lo, Index3(x, y, z));
          b.hi = glm::max(b.hi, Index3(x, y, z) + Index3(1));
        }
  occupiedCells_ = b.empty() ? Box3{} : Box3{b.lo * Index3(kBrickCells), glm::min(b.hi * Index3(kBrickCells), cellDims())};
}

std::vector<Box3> EmptySpaceMap::visibleVoxelBoxes(const Box3& within) const {
  std::vector<Box3> out;
  const Box3 clip = within.intersect({Index3(0), grid_.dims});
  if (clip.empty() || occupied_.empty()) return out;
  constexpr std::int64_t B = kBrickCells;
  // Voxel brick v holds voxels [B v, B v + B); cell brick c reads voxels
  // [B c, B c + B] (scanBrick), so v is read by cell bricks v - 1 and v on
  // each axis.
  auto occupied = [&](std::int64_t i, std::int64_t j, std::int64_t k) {
    if (i < 0 || j < 0 || k < 0 || i >= bdims_.x || j >= bdims_.y || k >= bdims_.z) return false;
    return occupied_[static_cast<std::size_t>((k * bdims_.y + j) * bdims_.x + i)] != 0;
  };
  auto needed = [&](std::int64_t i, std::int64_t j, std::int64_t k) {
    for (int dz = -1; dz <= 0; ++dz)
      for (int dy = -1; dy <= 0; ++dy)
        for (int dx = -1; dx <= 0; ++dx)
          if (occupied(i + dx, j + dy, k + dz)) return true;
    return false;
  };
  const Index3 lo = clip.lo / Index3(B), hi = (clip.hi + Index3(B - 1)) / Index3(B);
  for (std::int64_t k = lo.z; k < hi.z; ++k)
    for (std::int64_t j = lo.y; j < hi.y; ++j)
      for (std::int64_t i = lo.x; i < hi.x;) {
        if (!needed(i, j, k)) {
          ++i;
          continue;
        }
        std::int64_t e = i + 1;
        while (e < hi.x && needed(e, j, k)) ++e;
        const Box3 run = Box3{Index3(i, j, k) * Index3(B), Index3(e, j + 1, k + 1) * Index3(B)}.intersect(clip);
        if (!run.empty()) out.push_back(run);
        i = e;
      }
  return out;
}

double EmptySpaceMap::emptyFraction() const {
  if (occupied_.empty()) return 0.0;
  std::size_t n = 0;
  for (const auto o : occupied_) n += o == 0;
  return static_cast<double>(n) / static_cast<double>(occupied_.size());
}

}  // namespace pp5::gp
