#pragma once
// One pixel processor's ray caches: a hierarchical ray-sample cache
// (rendering/ray_cache.hpp) for each screen tile it holds, all for one view. The
// serial pipeline holds one tile, the whole image; a PP rank holds its share
// of the tiles, and keeps two sets as a double buffer so that a control
// change's caches are made while the old ones still take the frames sent
// before it.
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "core/ray_sample.hpp"
#include "core/tiles.hpp"
#include "rendering/ray_cache.hpp"

namespace pp5::pp {

class TileCaches {
public:
  // Caches for `rects` (tiles of an image `imageWidth` pixels wide); they
  // take memory at the first reset().
  TileCaches(std::vector<TileRect> rects, int imageWidth, const RayCacheSettings& settings, int threads);

  // Every cache for a new view: `imageCounts` are the lattice's sample counts
  // of the whole image (SampleLattice::counts(), row-major), every sample
  // transparent, the live mode `live`. The storage of the view before is
  // reused (RayCache::reset clears only what that view wrote).
  // pixelStride: the lattice's (RayCache::setPixelStride).
  void reset(std::span<const std::uint16_t> imageCounts, CompositeMode live, int pixelStride = 1);

  std::size_t size() const { return caches_.size(); }
  RayCache& operator[](std::size_t i) { return *caches_[i]; }
  const RayCache& operator[](std::size_t i) const { return *caches_[i]; }
  const std::vector<TileRect>& rects() const { return rects_; }

  // A new live mode for every cache (each recomposited at the next composite()).
  void setLiveMode(CompositeMode m);
  // Every cache's RayCache::setValueWindow, now and for caches made later.
  void setValueWindow(double lo, double hi);
  // Whether any cache took samples since its counters were last reset.
  bool anyPut() const;
  std::uint64_t memoryBytes() const;

private:
  // InputError when a view of these counts could need more memory than there is.
  void checkFits(std::span<const std::uint16_t> imageCounts) const;
  double window_[2] = {0.0, 255.0};
  std::vector<TileRect> rects_;
  int imageWidth_;
  RayCacheSettings settings_;
  int threads_;
  std::vector<std::unique_ptr<RayCache>> caches_;
  std::vector<std::uint16_t> counts_;  // one tile's counts, kept from reset to reset
};

}  // namespace pp5::pp
