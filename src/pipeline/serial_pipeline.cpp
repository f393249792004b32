#include "pipeline/serial_pipeline.hpp"

#include <chrono>
#include <functional>
#include <mutex>
#include <span>

#include "core/error.hpp"
#include "core/threads.hpp"
#include "reconstruction/stored_volume.hpp"

namespace pp5::serial {

namespace {

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

gp::Box3 wholeGrid(const Grid& g) { return {Index3(0), g.dims}; }

// Puts the sampler's batches into one cache as the sampling threads produce
// them (a full view holds tens of millions of samples, too many to gather
// first). Each thread puts its own batches into the cache at once (the
// sampler's threads sample different rays: RayCache::put(lane, ...)); with
// `onPut`, the batches go in one at a time under a lock, and `onPut(batch,
// ms)` follows each.
class CacheSink final : public gp::SampleSink {
public:
  CacheSink(pp::RayCache& cache, int threads) : cache_(cache) { cache.setPutLanes(resolveThreads(threads)); }
  CacheSink(pp::RayCache& cache, std::function<void(std::span<const RaySample>, double)> onPut)
      : cache_(cache), onPut_(std::move(onPut)) {}
  void consume(int thread, std::uint32_t, std::span<const RaySample> batch) override {
    if (!onPut_) return cache_.put(thread, batch.data(), batch.size());
    const std::lock_guard<std::mutex> lock(m_);
    const auto t = std::chrono::steady_clock::now();
    cache_.put(batch.data(), batch.size());
    if (onPut_) onPut_(batch, msSince(t));
  }

private:
  pp::RayCache& cache_;
  std::function<void(std::span<const RaySample>, double)> onPut_;  // none: every thread puts at once
  std::mutex m_;
};

}  // namespace

SerialPipeline::SerialPipeline(const Grid& grid, const PipelineSettings& s, std::uint64_t memoryLimitBytes)
    : s_(s), grid_(grid) {
  init(nullptr, memoryLimitBytes);
}

SerialPipeline::SerialPipeline(const Volume& volume, const PipelineSettings& s) : s_(s), grid_(volume.grid) {
  init(gp::storedVolume(volume), 0);
}

void SerialPipeline::init(std::unique_ptr<gp::Reconstructor> recon, std::uint64_t memoryLimitBytes) {
  if (s_.render.compositing.empty()) throw InputError("render.compositing: no composition mode given");
  live_ = checkedEnum(s_.render.compositing.front());
  s_.shading.threads = s_.render.threads;
  s_.shading.greyValues = compositesGreyValues(live_);
  s_.cache.validate();
  gp::GpUpdateSettings us;
  us.recon = s_.recon;
  us.render = s_.render;
  us.shading = s_.shading;
  us.tf = s_.tf;
  us.memoryLimitBytes = memoryLimitBytes;
  gp_ = std::make_unique<gp::GpUpdate>(grid_, us, makeCamera(s_.render, grid_), std::make_unique<gp::WholeShare>(grid_),
                                       std::move(recon));
  resetCaches();
  caches_->setValueWindow(s_.render.valueWindow.x, s_.render.valueWindow.y);
  resample(true);
}

ViewStats SerialPipeline::setCamera(const Camera& camera, double stepScale, int pixelStride) {
  using Clock = std::chrono::steady_clock;
  ViewStats st;
  auto t = Clock::now();
  s_.render.stepScale = stepScale;
  s_.render.pixelStride = pixelStride;
  gp_->setCamera(camera, stepScale, pixelStride);
  st.latticeMs = msSince(t);
  t = Clock::now();
  resetCaches();
  st.cacheMs = msSince(t);
  t = Clock::now();
  gp_->reshadeAll(true);
  st.shadeMs = msSince(t);
  resample(true, &st);
  return st;
}

void SerialPipeline::resetCaches() {
  const Camera& c = gp_->camera();
  if (!caches_ || caches_->rects()[0].width != c.width || caches_->rects()[0].height != c.height)
    caches_ = std::make_unique<pp::TileCaches>(std::vector<TileRect>{TileRect{0, 0, c.width, c.height}}, c.width,
                                               s_.cache, s_.render.threads);
  caches_->reset(gp_->lattice().counts(), live_, gp_->lattice().pixelStride());
}

void SerialPipeline::setStyle(const gp::ShadeSettings& shading, const TransferFunctionSettings& tf,
                              std::optional<pp::CompositeMode> live) {
  if (live) {
    live_ = checkedEnum(*live);
    std::erase(s_.render.compositing, live_);
    s_.render.compositing.insert(s_.render.compositing.begin(), live_);
    caches_->setLiveMode(live_);
    gp_->setLiveMode(live_);
  }
  s_.shading = shading;
  s_.shading.threads = s_.render.threads;
  s_.shading.greyValues = compositesGreyValues(live_);
  s_.tf = tf;
  gp_->setStyle(shading, tf);
  gp_->reshadeAll(false);
  resample(false);
}

void SerialPipeline::setLiveMode(pp::CompositeMode m) {
  if (compositesGreyValues(m) != compositesGreyValues(live_)) return setStyle(s_.shading, s_.tf, m);
  live_ = m;
  std::erase(s_.render.compositing, m);
  s_.render.compositing.insert(s_.render.compositing.begin(), m);
  caches_->setLiveMode(m);
  gp_->setLiveMode(m);
  (*caches_)[0].composite();
}

void SerialPipeline::setValueWindow(double lo, double hi) {
  s_.render.valueWindow = glm::dvec2(lo, hi);
  caches_->setValueWindow(lo, hi);
  (*caches_)[0].composite();
}

void SerialPipeline::resample(bool cleared, ViewStats* st) {
  using Clock = std::chrono::steady_clock;
  pp::RayCache& cache = (*caches_)[0];
  if (!cleared) cache.clear();
  auto t = Clock::now();
  const std::uint64_t before = cache.counters().samplesPut;
  CacheSink sink(cache, s_.render.threads);
  gp_->sampleAll(sink);
  if (st) {
    st->samples = cache.counters().samplesPut - before;
    st->sampleMs = msSince(t);
  }
  t = Clock::now();
  cache.composite();
  if (st) st->compositeMs = msSince(t);
}

FrameStats SerialPipeline::insert(const Frame& f, const Mat4& pose, double timeS) {
  using Clock = std::chrono::steady_clock;
  FrameStats st;
  st.index = frames_++;

  auto t = Clock::now();
  const gp::InsertResult r = gp_->reconstructor().insert(f, pose, timeS);
  st.reconMs = msSince(t);
  st.fillInSlices = r.fillInSlices;
  st.dirtyBricks = r.dirty.bricks().size();
  st.dirtyVoxels = r.dirty.voxelCount();
  if (r.dirty.empty()) {
    if (census_) census_->addFrame(r.dirty, {}, gp_->lattice(), f.pixels.size());
    return st;
  }

  t = Clock::now();
  gp_->shadeChanged(r.dirty, r.changedRuns);
  for (const gp::Box3& b : gp_->lastShaded()) st.shadedVoxels += b.intersect(wholeGrid(grid_)).voxelCount();
  st.shadeMs = msSince(t);
  if (census_) census_->addFrame(r.dirty, gp_->lastShaded(), gp_->lattice(), f.pixels.size());

  t = Clock::now();
  pp::RayCache& cache = (*caches_)[0];
  // Sampling and putting overlap; the time of the puts is counted as compositing.
  double putMs = 0.0;
  CacheSink sink(cache, [&](std::span<const RaySample> batch, double ms) {
    st.samples += batch.size();
    putMs += ms;
    if (census_) census_->addSamples(batch, gp_->lattice());
  });
  gp_->sampleChanged(sink);
  st.dbufferPixels = gp_->dbuffer().touched().size();
  st.sampleMs = msSince(t) - putMs;

  t = Clock::now();
  const pp::CompositeStats cs = cache.composite();
  st.compositeMs = msSince(t) + putMs;
  st.raysComposited = cs.rays;
  st.blocksComposited = cs.blocks;
  return st;
}

void SerialPipeline::finish() {
  gp_->reconstructor().finish();
  gp_->reshadeAll(false);
  resample(false);
}

pp::TileImage SerialPipeline::renderFromScratch(pp::CompositeMode mode) const {
  const Camera& camera = gp_->camera();
  gp::ShadeBuffer shade(grid_);
  gp::ShadeSettings shading = gp_->settings().shading;
  shading.greyValues = compositesGreyValues(mode);
  RenderSettings render = s_.render;
  std::erase(render.compositing, mode);
  render.compositing.insert(render.compositing.begin(), mode);
  gp::shade(gp_->reconstructor().output(), gp_->transferFunction(), shading, camera, wholeGrid(grid_), shade);
  const gp::EmptySpaceMap space(shade, s_.render.threads);
  pp::RayCache cache(TileRect{0, 0, camera.width, camera.height}, camera.width, gp_->lattice().counts(), s_.cache, mode,
                     s_.render.threads);
  cache.setPixelStride(gp_->lattice().pixelStride());
  cache.setValueWindow(s_.render.valueWindow.x, s_.render.valueWindow.y);
  CacheSink sink(cache, s_.render.threads);
  gp::sampleAll(shade, gp_->lattice(), render, sink, &space);
  cache.composite();
  return cache.image();
}

}  // namespace pp5::serial
