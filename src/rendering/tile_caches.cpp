#include "rendering/tile_caches.hpp"

#include <algorithm>

#include <fmt/format.h>

#include "core/error.hpp"
#include "core/grid.hpp"

namespace pp5::pp {

TileCaches::TileCaches(std::vector<TileRect> rects, int imageWidth, const RayCacheSettings& settings, int threads)
    : rects_(std::move(rects)), imageWidth_(imageWidth), settings_(settings), threads_(threads) {}

void TileCaches::reset(std::span<const std::uint16_t> imageCounts, CompositeMode live, int pixelStride) {
  checkFits(imageCounts);
  for (std::size_t i = 0; i < rects_.size(); ++i) {
    const TileRect& r = rects_[i];
    PP5_CHECK_LE(static_cast<std::size_t>(r.y0 + r.height) * static_cast<std::size_t>(imageWidth_),
                 imageCounts.size());
    std::span<const std::uint16_t> counts;
    if (r.x0 == 0 && r.width == imageWidth_) {
      // Whole rows: the image's counts are the tile's.
      counts = imageCounts.subspan(static_cast<std::size_t>(r.y0) * static_cast<std::size_t>(imageWidth_),
                                   static_cast<std::size_t>(r.width) * static_cast<std::size_t>(r.height));
    } else {
      counts_.resize(static_cast<std::size_t>(r.width) * static_cast<std::size_t>(r.height));
      for (int y = 0; y < r.height; ++y)
        std::copy_n(imageCounts.data() + static_cast<std::size_t>(r.y0 + y) * static_cast<std::size_t>(imageWidth_) +
                        static_cast<std::size_t>(r.x0),
                    r.width, counts_.data() + static_cast<std::size_t>(y) * static_cast<std::size_t>(r.width));
      counts = counts_;
    }
    if (i < caches_.size()) {
      caches_[i]->reset(counts, live);
    } else {
      caches_.push_back(std::make_unique<RayCache>(r, imageWidth_, counts, settings_, live, threads_));
      caches_.back()->setValueWindow(window_[0], window_[1]);
    }
    caches_[i]->setPixelStride(pixelStride);
  }
}

void TileCaches::checkFits(std::span<const std::uint16_t> imageCounts) const {
  // Every sample written (an opaque volume) at worst, with each block's
  // partial and flag, each ray's record and pixel, and a flag per page: what
  // a view's caches can come to need. The storage of the view before is
  // given back first, so it counts as available.
  std::uint64_t samples = 0, rays = 0;
  for (const TileRect& r : rects_) {
    rays += static_cast<std::uint64_t>(r.width) * static_cast<std::uint64_t>(r.height);
    for (int y = 0; y < r.height; ++y)
      for (int x = 0; x < r.width; ++x)
        samples += imageCounts[static_cast<std::size_t>(r.y0 + y) * static_cast<std::size_t>(imageWidth_) +
                               static_cast<std::size_t>(r.x0 + x)];
  }
  const auto blocks = samples / static_cast<std::uint64_t>(settings_.blockSize) + rays;
  // A ray's record and dirty-list entry take at most 32 bytes, its pixel 16.
  const std::uint64_t need = samples * sampleFormatBytes(settings_.format) + blocks * (sizeof(RayCache::Partial) + 1) +
                             rays * (32 + 16) + samples / 64;
  const std::uint64_t have = availableMemoryBytes() + memoryBytes();
  if (need > have)
    throw InputError(fmt::format(
        "the ray cache of this view ({} rays, {} lattice samples) could need {:.1f} GiB, but {:.1f} GiB is "
        "available: use a smaller image (render.width, render.height), a longer step (render.step_mm) or fewer "
        "samples per ray (render.max_samples)",
        rays, samples, static_cast<double>(need) / (1u << 30), static_cast<double>(have) / (1u << 30)));
}

void TileCaches::setLiveMode(CompositeMode m) {
  for (auto& c : caches_) c->setLiveMode(m);
}

void TileCaches::setValueWindow(double lo, double hi) {
  window_[0] = lo;
  window_[1] = hi;
  for (auto& c : caches_) c->setValueWindow(lo, hi);
}

bool TileCaches::anyPut() const {
  return std::any_of(caches_.begin(), caches_.end(), [](const auto& c) { return c->counters().samplesPut != 0; });
}

std::uint64_t TileCaches::memoryBytes() const {
  std::uint64_t n = 0;
  for (const auto& c : caches_) n += c->memoryBytes();
  return n;
}

}  // namespace pp5::pp
