#include "rendering/empty_space.hpp"

#include <algorithm>
#include <bit>
#include <cstring>

#include <omp.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.hpp"
#include "core/threads.hpp"

namespace pp5::gp {

namespace {

// The alpha > 0 bits of 64 voxels.
std::uint64_t pack64(const ShadeVoxel* v) {
#if defined(__SSE2__)
  // Alpha is each voxel's high byte (r, g, b, a in memory, little-endian).
  static_assert(std::endian::native == std::endian::little);
  std::uint64_t bits = 0;
  const __m128i zero = _mm_setzero_si128();
  for (int q = 0; q < 16; ++q) {
    const __m128i x = _mm_loadu_si128(reinterpret_cast<const __m128i*>(v + 4 * q));
    const __m128i visible = _mm_cmpgt_epi32(_mm_srli_epi32(x, 24), zero);
    bits |= static_cast<std::uint64_t>(_mm_movemask_ps(_mm_castsi128_ps(visible))) << (4 * q);
  }
  return bits;
#else
  std::uint64_t bits = 0;
  for (int i = 0; i < 64; ++i) bits |= static_cast<std::uint64_t>(v[i].a != 0) << i;
  return bits;
#endif
}

// The 64 bits of `bits` from bit b on (the words after b's are read).
inline std::uint64_t bitsFrom(const std::uint64_t* bits, std::int64_t b) {
  const std::int64_t q = b >> 6;
  const int r = static_cast<int>(b & 63);
  return r == 0 ? bits[q] : (bits[q] >> r) | (bits[q + 1] << (64 - r));
}

// Words of 64 in parallel loops: enough per chunk to amortise the scheduling.
constexpr std::int64_t kWordChunk = 1024;

}  // namespace

EmptySpaceMap::EmptySpaceMap(const ShadeBuffer& shade, int threads) : grid_(shade.grid()) {
  const Index3& d = grid_.dims;
  PP5_CHECK_GE(d.x, 2);
  PP5_CHECK_GE(d.y, 2);
  PP5_CHECK_GE(d.z, 2);
  bdims_ = (cellDims() + Index3(kBrickCells - 1)) / Index3(kBrickCells);
  const std::size_t n = static_cast<std::size_t>(bdims_.x * bdims_.y * bdims_.z);
  occupied_.assign(n, 0);
  dist_.assign(n, 0);
  // A cell's word reads the voxel words up to (x + 1, y + 1, z + 1) from its
  // corner, one slice and one row on, and the word after that.
  const auto voxels = static_cast<std::int64_t>(grid_.voxelCount());
  const std::int64_t words = (voxels + 63) / 64;
  const std::int64_t reach = static_cast<std::int64_t>(grid_.linear(1, 1, 1));
  voxelBits_.assign(static_cast<std::size_t>(words + reach / 64 + 2), 0);
  cellBits_.assign(static_cast<std::size_t>(words + 1), 0);
  const int nt = resolveThreads(threads);
  const std::int64_t chunks = (words + kWordChunk - 1) / kWordChunk;
#pragma omp parallel num_threads(nt)
  {
    // Each chunk writes its own words only.
#pragma omp for schedule(static)
    for (std::int64_t c = 0; c < chunks; ++c)
      packVoxels(shade, c * kWordChunk * 64, std::min(voxels, (c + 1) * kWordChunk * 64));
#pragma omp for schedule(static)
    for (std::int64_t c = 0; c < chunks; ++c) computeCellWords(c * kWordChunk, std::min(words, (c + 1) * kWordChunk));
    const std::int64_t slices = bdims_.z * bdims_.y;
#pragma omp for schedule(dynamic, 4)
    for (std::int64_t sl = 0; sl < slices; ++sl)
      for (std::int64_t bi = 0; bi < bdims_.x; ++bi) scanBrick(bi, sl % bdims_.y, sl / bdims_.y);
  }
  computeDistances();
}

void EmptySpaceMap::packVoxels(const ShadeBuffer& shade, std::int64_t first, std::int64_t last) {
  const ShadeVoxel* v = shade.data();
  for (std::int64_t i = first; i < last;) {
    const std::int64_t w = i >> 6;
    const std::int64_t end = std::min(last, (w + 1) << 6);
    if (end - i == 64) {
      voxelBits_[static_cast<std::size_t>(w)] = pack64(v + i);
    } else {
      std::uint64_t bits = 0;
      for (std::int64_t j = i; j < end; ++j) bits |= static_cast<std::uint64_t>(v[j].a != 0) << (j & 63);
      const std::uint64_t mask = ((std::uint64_t{1} << (end - i)) - 1) << (i & 63);
      std::uint64_t& word = voxelBits_[static_cast<std::size_t>(w)];
      word = (word & ~mask) | bits;
    }
    i = end;
  }
}

void EmptySpaceMap::computeCellWords(std::int64_t w0, std::int64_t w1) {
  const std::int64_t sy = grid_.dims.x, sz = grid_.dims.x * grid_.dims.y;
  const std::int64_t offsets[8] = {0, 1, sy, sy + 1, sz, sz + 1, sz + sy, sz + sy + 1};
  const std::uint64_t* a = voxelBits_.data();
  for (std::int64_t w = w0; w < w1; ++w) {
    std::uint64_t acc = 0;
    for (const std::int64_t o : offsets) acc |= bitsFrom(a, (w << 6) + o);
    cellBits_[static_cast<std::size_t>(w)] = acc;
  }
}

bool EmptySpaceMap::scanBrick(std::int64_t bi, std::int64_t bj, std::int64_t bk) {
  const Index3 lo = Index3(bi, bj, bk) * Index3(kBrickCells);
  const Index3 hi = glm::min(lo + Index3(kBrickCells), cellDims());
  const std::uint64_t mask = (std::uint64_t{1} << (hi.x - lo.x)) - 1;  // at most 8 cells along x
  bool any = false;
  for (std::int64_t z = lo.z; z < hi.z && !any; ++z)
    for (std::int64_t y = lo.y; y < hi.y && !any; ++y)
      any = (bitsFrom(cellBits_.data(), static_cast<std::int64_t>(grid_.linear(lo.x, y, z))) & mask) != 0;
  std::uint8_t& o = occupied_[static_cast<std::size_t>((bk * bdims_.y + bj) * bdims_.x + bi)];
  const std::uint8_t was = o;
  o = any ? 1 : 0;
  return o != was;
}

void EmptySpaceMap::update(const ShadeBuffer& shade, std::span<const Box3> changed) {
  checkSameGrid(shade.grid(), grid_);
  PP5_CHECK(hasCellBits());
  std::vector<Box3> inGrid;
  for (const Box3& b0 : changed) {
    const Box3 b = b0.intersect({Index3(0), grid_.dims});
    if (!b.empty()) inGrid.push_back(b);
  }
  if (inGrid.empty()) return;
  // The voxels, then the cells that read them (every voxel first: a cell's
  // stencil may reach into another box), then their bricks.
  for (const Box3& b : inGrid)
    for (std::int64_t z = b.lo.z; z < b.hi.z; ++z)
      for (std::int64_t y = b.lo.y; y < b.hi.y; ++y) {
        const auto i = static_cast<std::int64_t>(grid_.linear(b.lo.x, y, z));
        packVoxels(shade, i, i + (b.hi.x - b.lo.x));
      }
  std::vector<Box3> cellBoxes;
  for (const Box3& b : inGrid) {
    // Voxel v is read by cells v - 1 and v.
    const Box3 cells{glm::max(b.lo - Index3(1), Index3(0)), glm::min(b.hi, cellDims())};
    if (cells.empty()) continue;
    cellBoxes.push_back(cells);
    for (std::int64_t z = cells.lo.z; z < cells.hi.z; ++z)
      for (std::int64_t y = cells.lo.y; y < cells.hi.y; ++y) {
        const auto i0 = static_cast<std::int64_t>(grid_.linear(cells.lo.x, y, z));
        computeCellWords(i0 >> 6, ((i0 + (cells.hi.x - cells.lo.x) - 1) >> 6) + 1);
      }
  }
  std::vector<std::uint8_t> seen(occupied_.size(), 0);
  // A brick's occupancy changed: the distances, which follow from it, change.
  // Bricks that became occupied only lower them, near the brick; one that
  // became empty can raise any, and all are recomputed.
  std::vector<Index3> filled;
  bool emptied = false;
  for (const Box3& c : cellBoxes) {
    const Index3 clo = c.lo / Index3(kBrickCells), chi = (c.hi - Index3(1)) / Index3(kBrickCells);
    for (std::int64_t k = clo.z; k <= chi.z; ++k)
      for (std::int64_t j = clo.y; j <= chi.y; ++j)
        for (std::int64_t i = clo.x; i <= chi.x; ++i) {
          const auto id = static_cast<std::size_t>((k * bdims_.y + j) * bdims_.x + i);
          if (seen[id]) continue;
          seen[id] = 1;
          if (!scanBrick(i, j, k)) continue;
          if (occupied_[id]) filled.emplace_back(i, j, k);
          else emptied = true;
        }
  }
  if (emptied || !lowerDistances(filled)) {
    computeDistances();
  }
}

bool EmptySpaceMap::lowerDistances(std::span<const Index3> filled) {
  // The map is the chessboard distance to the nearest occupied brick (capped
  // at 255). With the bricks `filled` occupied too, each brick takes the
  // smaller of its distance and its distance to them: a breadth-first walk
  // from them over the 26 neighbours, through the bricks it lowers only (a
  // brick it does not lower is no farther than the walk's level from an
  // occupied brick already, and so are the bricks beyond it, by one per
  // step). Its work is the lowered bricks'; past a 32nd of the map the
  // caller recomputes everything instead (false).
  if (filled.empty()) return true;
  const std::int64_t X = bdims_.x, Y = bdims_.y, Z = bdims_.z;
  const std::size_t budget = dist_.size() / 32;
  std::vector<std::int64_t> level, next;
  for (const Index3& o : filled) {
    const std::int64_t id = (o.z * Y + o.y) * X + o.x;
    dist_[static_cast<std::size_t>(id)] = 0;
    level.push_back(id);
    const Box3 cells = cellsOfBricks({o, o + Index3(1)});
    occupiedCells_ = occupiedCells_.empty() ? cells
                                            : Box3{glm::min(occupiedCells_.lo, cells.lo), glm::max(occupiedCells_.hi, cells.hi)};
  }
  std::size_t work = 0;
  for (int c = 1; c < 255 && !level.empty(); ++c) {
    const auto v = static_cast<std::uint8_t>(c);
    next.clear();
    for (const std::int64_t id : level) {
      const std::int64_t x = id % X, y = (id / X) % Y, z = id / (X * Y);
      for (std::int64_t zz = std::max<std::int64_t>(z - 1, 0); zz <= std::min(z + 1, Z - 1); ++zz)
        for (std::int64_t yy = std::max<std::int64_t>(y - 1, 0); yy <= std::min(y + 1, Y - 1); ++yy)
          for (std::int64_t xx = std::max<std::int64_t>(x - 1, 0); xx <= std::min(x + 1, X - 1); ++xx) {
            const std::int64_t n = (zz * Y + yy) * X + xx;
            std::uint8_t& d = dist_[static_cast<std::size_t>(n)];
            if (d > v) {
              d = v;
              next.push_back(n);
            }
          }
    }
    work += next.size();
    if (work > budget) return false;
    std::swap(level, next);
  }
  return true;
}

void EmptySpaceMap::assignBricks(const EmptySpaceMap& from) {
  grid_ = from.grid_;
  bdims_ = from.bdims_;
  occupiedCells_ = from.occupiedCells_;
  occupied_ = from.occupied_;
  dist_ = from.dist_;
  voxelBits_.clear();
  cellBits_.clear();
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
  occupiedCells_ = b.empty() ? Box3{} : cellsOfBricks(b);
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
