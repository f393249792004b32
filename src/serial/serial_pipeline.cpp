#include "serial/serial_pipeline.hpp"

#include <chrono>
#include <functional>
#include <mutex>
#include <span>

#include "core/error.hpp"

namespace pp5::serial {

namespace {

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

gp::Box3 wholeGrid(const Grid& g) { return {Index3(0), g.dims}; }

// Puts the sampler's batches into one cache as the sampling threads produce
// them (a full view holds tens of millions of samples, too many to gather
// first); `onPut(n, ms)` after each batch, under the same lock.
class CacheSink final : public gp::SampleSink {
public:
  explicit CacheSink(pp::RayCache& cache, std::function<void(std::size_t, double)> onPut = {})
      : cache_(cache), onPut_(std::move(onPut)) {}
  void consume(int, std::uint32_t, std::span<const RaySample> batch) override {
    const std::lock_guard<std::mutex> lock(m_);
    const auto t = std::chrono::steady_clock::now();
    cache_.put(batch.data(), batch.size());
    if (onPut_) onPut_(batch.size(), msSince(t));
  }

private:
  pp::RayCache& cache_;
  std::function<void(std::size_t, double)> onPut_;
  std::mutex m_;
};

}  // namespace

SerialPipeline::SerialPipeline(const Grid& grid, const PipelineSettings& s, std::uint64_t memoryLimitBytes)
    : s_(s), grid_(grid), tf_(s.tf) {
  if (s_.render.compositing.empty()) throw InputError("render.compositing: no composition mode given");
  live_ = pp::compositeModeFromName(s_.render.compositing.front());
  s_.shading.threads = s_.render.threads;
  s_.cache.validate();
  // The reconstruction, then the shade buffer (4 bytes a voxel) on top of it.
  recon_ = gp::makeReconstructor(grid_, s_.recon, memoryLimitBytes, "reconstruction grid ([grid])");
  checkGridFits(grid_, 4, "shade buffer ([grid])", memoryLimitBytes);
  shade_ = gp::ShadeBuffer(grid_);
  useCamera(makeCamera(s_.render, grid_));
  resampleAll(true);
}

void SerialPipeline::setCamera(const Camera& camera) {
  useCamera(camera);
  // The values and the style are as they were, so every voxel's opacity is
  // too: only the voxels that were visible need new light, and the
  // empty-space map (opacity only) stays as it is.
  gp::shade(recon_->output(), tf_, s_.shading, camera_, space_.visibleVoxelBoxes(wholeGrid(grid_)), shade_);
  resample(true);
}

void SerialPipeline::useCamera(const Camera& camera) {
  camera_ = camera;
  lattice_ = SampleLattice(camera_, grid_, s_.render.step(grid_), s_.render.maxSamples, s_.render.threads);
  const TileRect tile{0, 0, camera_.width, camera_.height};
  if (cache_ && cache_->tile().width == tile.width && cache_->tile().height == tile.height) {
    cache_->reset(lattice_.counts());
  } else {
    cache_ = std::make_unique<pp::RayCache>(tile, camera_.width, lattice_.counts(), s_.cache, live_, 1);
    cache_->setThreads(s_.render.threads);
  }
}

void SerialPipeline::setStyle(const gp::ShadeSettings& shading, const TransferFunctionSettings& tf) {
  s_.shading = shading;
  s_.shading.threads = s_.render.threads;
  s_.tf = tf;
  tf_ = TransferFunction(tf);
  resampleAll();
}

void SerialPipeline::setLiveMode(pp::CompositeMode m) {
  live_ = m;
  cache_->setLiveMode(m);
  cache_->composite();
}

void SerialPipeline::resampleAll(bool cleared) {
  gp::shade(recon_->output(), tf_, s_.shading, camera_, wholeGrid(grid_), shade_);
  space_ = gp::EmptySpaceMap(shade_, s_.render.threads);
  resample(cleared);
}

void SerialPipeline::resample(bool cleared) {
  if (!cleared) cache_->clear();
  CacheSink sink(*cache_);
  gp::sampleAll(shade_, lattice_, s_.render, sink, &space_);
  cache_->composite();
}

FrameStats SerialPipeline::insert(const Frame& f, const Mat4& pose, double timeS) {
  using Clock = std::chrono::steady_clock;
  FrameStats st;
  st.index = frames_++;

  auto t = Clock::now();
  const gp::InsertResult r = recon_->insert(f, pose, timeS);
  st.reconMs = msSince(t);
  st.fillInSlices = r.fillInSlices;
  st.dirtyBricks = r.dirty.bricks().size();
  st.dirtyVoxels = r.dirty.voxelCount();
  if (r.dirty.empty()) return st;

  t = Clock::now();
  // The dirty bricks and their gradient margin (what shade(dirty) shades),
  // worked out once for shading, the empty-space map and the D-buffer.
  const std::vector<gp::Box3> shaded = gp::shadingBoxes(r.dirty);
  gp::shade(recon_->output(), tf_, s_.shading, camera_, shaded, shade_);
  for (const gp::Box3& b : shaded) st.shadedVoxels += b.intersect(wholeGrid(grid_)).voxelCount();
  spaceBefore_ = space_;  // a few kB (a byte per 8^3 cells); assigning keeps the storage
  space_.update(shade_, shaded);
  st.shadeMs = msSince(t);

  t = Clock::now();
  const std::vector<gp::WorldBox> boxes = gp::stencilBoxes(grid_, shaded);
  dbuf_.build(camera_, boxes);
  st.dbufferPixels = dbuf_.touched().size();
  // Sampling and putting overlap; the time of the puts is counted as compositing.
  double putMs = 0.0;
  CacheSink sink(*cache_, [&](std::size_t n, double ms) {
    st.samples += n;
    putMs += ms;
  });
  gp::sampleRegion(shade_, lattice_, dbuf_, s_.render, sink, &space_, {}, &spaceBefore_);
  st.sampleMs = msSince(t) - putMs;

  t = Clock::now();
  const pp::CompositeStats cs = cache_->composite();
  st.compositeMs = msSince(t) + putMs;
  st.raysComposited = cs.rays;
  st.blocksComposited = cs.blocks;
  return st;
}

void SerialPipeline::finish() {
  recon_->finish();
  resampleAll();
}

pp::TileImage SerialPipeline::renderFromScratch(pp::CompositeMode mode) const {
  gp::ShadeBuffer shade(grid_);
  gp::shade(recon_->output(), tf_, s_.shading, camera_, wholeGrid(grid_), shade);
  const gp::EmptySpaceMap space(shade, s_.render.threads);
  pp::RayCache cache(TileRect{0, 0, camera_.width, camera_.height}, camera_.width, lattice_.counts(), s_.cache, mode,
                     s_.render.threads);
  CacheSink sink(cache);
  gp::sampleAll(shade, lattice_, s_.render, sink, &space);
  cache.composite();
  return cache.image();
}

}  // namespace pp5::serial
