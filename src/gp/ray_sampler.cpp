#include "gp/ray_sampler.hpp"

#include "gp/ray_walk.hpp"

namespace pp5::gp {

// ---------------------------------------------------------------------------
// Sinks

void SampleCollector::consume(int, std::uint32_t tile, std::span<const RaySample> samples) {
  std::lock_guard<std::mutex> lock(m_);
  if (tile >= tiles_.size()) tiles_.resize(tile + 1);
  tiles_[tile].insert(tiles_[tile].end(), samples.begin(), samples.end());
}

std::vector<RaySample> SampleCollector::samples() const {
  std::lock_guard<std::mutex> lock(m_);
  std::vector<RaySample> out;
  std::size_t n = 0;
  for (const auto& t : tiles_) n += t.size();
  out.reserve(n);
  for (const auto& t : tiles_) out.insert(out.end(), t.begin(), t.end());
  return out;
}

std::size_t SampleCollector::size() const {
  std::lock_guard<std::mutex> lock(m_);
  std::size_t n = 0;
  for (const auto& t : tiles_) n += t.size();
  return n;
}

void SampleCollector::clear() {
  std::lock_guard<std::mutex> lock(m_);
  tiles_.clear();
}

std::uint32_t workTileCount(int width, int height, int tileSize) {
  PP5_CHECK_GE(width, 0);
  PP5_CHECK_GE(height, 0);
  return TileGrid(width, height, tileSize).count();
}

void sampleAll(const ShadeBuffer& shade, const SampleLattice& lattice, const RenderSettings& settings,
               SampleSink& sink, const EmptySpaceMap* space, const SamplerOptions& options) {
  checkSameGrid(shade.grid(), lattice.grid());
  PP5_CHECK_GT(options.batchSamples, std::size_t{0});
  const int W = lattice.width(), H = lattice.height();
  const TileGrid tiles(W, H, options.tileSize);
  const TileSelection selection(tiles, options.workTiles);
  const std::int64_t workCount =
      selection.all ? static_cast<std::int64_t>(tiles.count()) : static_cast<std::int64_t>(selection.list.size());
  std::optional<OwnedCells> owned;
  if (options.ownedCells) owned.emplace(*options.ownedCells, lattice.grid().dims - Index3(1));
  if (workCount == 0 || (owned && owned->empty())) return;
  EmptySpaceMap own;
  if (!space) {
    own = EmptySpaceMap(shade, settings.threads);
    space = &own;
  }
  checkSameGrid(space->grid(), lattice.grid());
  const Interpolator interp(shade);
  const float e = exponentOf(lattice, settings);
  PP5_CHECK(space->hasCellBits());
  const std::uint8_t* dist = space->distances();
  const std::uint64_t* cells = space->cellBits();
  const Index3 bd = space->brickDims();
  const Box3 occupied = space->occupiedCells();
  if (occupied.empty()) return;
  // A visible sample's cell is in the visible bricks' bounds: where those
  // miss the owned cells, every owned sample is transparent.
  if (owned && owned->box().intersect(occupied).empty()) return;
  // Where a ray is walked: the visible bricks' bounds grown by the margin,
  // and with ownedCells the part of it that can hold an owned cell. (The two
  // boxes meet, so the clip below gives the intersection of their ranges.)
  double clipLo[3], clipHi[3];
  for (int a = 0; a < 3; ++a) {
    clipLo[a] = occupied.lo[a] - kSkipMarginVoxels;
    clipHi[a] = occupied.hi[a] + kSkipMarginVoxels;
    if (owned) {
      clipLo[a] = std::max(clipLo[a], owned->lo(a));
      clipHi[a] = std::min(clipHi[a], owned->hi(a));
    }
  }
  const int nt = static_cast<int>(std::min<std::int64_t>(resolveThreads(settings.threads), workCount));

#pragma omp parallel num_threads(nt)
  {
    Batcher out(sink, omp_get_thread_num(), options.batchSamples);
    RayStage stage(lattice.maxSamples(), e, compositesGreyValues(settings.compositing.front()));
    // This thread's copies: the walk reads them for every ray.
    const OwnedCells* const mine = owned ? &*owned : nullptr;
    const double lo[3] = {clipLo[0], clipLo[1], clipLo[2]}, hi[3] = {clipHi[0], clipHi[1], clipHi[2]};
#pragma omp for schedule(dynamic, 1)
    for (std::int64_t w = 0; w < workCount; ++w) {
      const std::int64_t t = selection.all ? w : selection.list[static_cast<std::size_t>(w)];
      out.startTile(static_cast<std::uint32_t>(t));
      const int x0 = static_cast<int>(t % tiles.nx) * tiles.size, y0 = static_cast<int>(t / tiles.nx) * tiles.size;
      const int x1 = std::min(W, x0 + tiles.size), y1 = std::min(H, y0 + tiles.size);
      for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x) {
          const auto pixel = static_cast<std::uint32_t>(y) * static_cast<std::uint32_t>(W) + static_cast<std::uint32_t>(x);
          const std::uint32_t n = lattice.count(pixel);
          if (n == 0) continue;
          const VoxelRay vr = lattice.voxelRay(pixel);
          // Only the part of the ray inside the visible bricks' bounds (grown
          // by the margin) can have a visible sample; with ownedCells, only
          // its part in the owned box (grown likewise) an owned one.
          double kIn = 0.0, kOut = static_cast<double>(n - 1);
          const BrickJump jump(vr);
          const double* inv = jump.inv;
          for (int a = 0; a < 3; ++a) {
            const double b0 = vr.base[a], dl = vr.delta[a];
            if (dl == 0.0) {
              if (b0 < lo[a] || b0 > hi[a]) kOut = -1.0;
              continue;
            }
            const double t0 = (lo[a] - b0) * inv[a], t1 = (hi[a] - b0) * inv[a];
            kIn = std::max(kIn, std::min(t0, t1));
            kOut = std::min(kOut, std::max(t0, t1));
          }
          if (!(kOut >= kIn)) continue;
          const std::uint32_t k = static_cast<std::uint32_t>(std::ceil(kIn));
          const std::uint32_t kEnd = static_cast<std::uint32_t>(kOut);  // floor: kOut >= 0
          if (k > kEnd) continue;
          if (mine) {  // the clip was conservative: now the exact cells
            std::int64_t k0 = k, k1 = kEnd;
            if (mine->exact(interp, vr, k0, k1))
              walkVisible(interp, vr, jump, dist, cells, bd, static_cast<std::uint32_t>(k0),
                          static_cast<std::uint32_t>(k1), stage);
          } else {
            walkVisible(interp, vr, jump, dist, cells, bd, k, kEnd, stage);
          }
          stage.emit(pixel, out);
        }
      out.flush();
    }
  }
}

RaySample sampleAt(const ShadeBuffer& shade, const SampleLattice& lattice, const RenderSettings& settings,
                   std::uint32_t pixel, std::uint32_t k) {
  checkSameGrid(shade.grid(), lattice.grid());
  const Interpolator interp(shade);
  RayStage stage(1, exponentOf(lattice, settings), compositesGreyValues(settings.compositing.front()));
  Cells4 c;
  interp.locate4(lattice.voxelRay(pixel), k, c);
  interp.at(c, 0, stage.slot());
  stage.commit(k);
  SampleCollector one;
  Batcher out(one, 0, 1);
  stage.emit(pixel, out);
  out.flush();
  return one.samples().at(0);
}

}  // namespace pp5::gp
