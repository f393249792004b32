#include "host/local_pipeline.hpp"

#include <algorithm>
#include <cstdio>

#include <spdlog/spdlog.h>

namespace pp5::host {

namespace {

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

template <typename T, typename F>
double medianOf(const std::vector<T>& v, F f) {
  std::vector<double> x;
  x.reserve(v.size());
  for (const T& e : v) x.push_back(f(e));
  return median(std::move(x));
}

}  // namespace

LocalPipeline::LocalPipeline(const RunJob& job)
    : j_(job), pipe_(std::make_unique<serial::SerialPipeline>(job.grid, job.pipeline, job.memoryLimitBytes)) {
  logMemory();
  if (!j_.census.empty()) {
    census_ = std::make_unique<serial::WorkCensus>(j_.grid, j_.pipeline.render.width, j_.pipeline.render.height);
    pipe_->setCensus(census_.get());
  }
}

LocalPipeline::LocalPipeline(const Volume& volume, const RunJob& job)
    : j_(job), pipe_(std::make_unique<serial::SerialPipeline>(volume, job.pipeline)) {}

void LocalPipeline::logMemory() const {
  spdlog::info("run: ray cache {:.1f} MiB ({} samples, {} format), shade buffer {:.1f} MiB",
               static_cast<double>(pipe_->cache().memoryBytes()) / (1 << 20), pipe_->cache().sampleCount(),
               pp::sampleFormatName(pipe_->cache().format()),
               static_cast<double>(pipe_->shadeBuffer().memoryBytes()) / (1 << 20));
}

std::vector<std::string> LocalPipeline::statsColumns() const {
  return {"frame",        "epoch",        "recon_ms",      "shade_ms",     "sample_ms",
          "composite_ms", "total_ms",     "fill_in_slices", "dirty_bricks", "dirty_voxels",
          "shaded_voxels", "dbuffer_rays", "samples",       "rays_composited", "blocks_composited"};
}

// The page is served at least every 5 ms while one is open.
std::chrono::milliseconds LocalPipeline::frameWait(bool steered) const {
  return std::chrono::milliseconds(steered ? 5 : 50);
}

void LocalPipeline::insert(AcquiredFrame& a) {
  const serial::FrameStats st = pipe_->insert(a.frame, a.imageToReference, a.timeS);
  const std::uint64_t k = tally_.frames++;
  latency_.arrived(a.arrival);
  // The latency from the frame's arrival, its wait in the queue included.
  latency_.imageHas(static_cast<std::int64_t>(k), static_cast<std::int64_t>(k), [](std::int64_t, double) {});
  tally_.gpBusyMs += st.reconMs + st.shadeMs + st.sampleMs;
  tally_.ppBusyMs += st.compositeMs;
  frameStats_.push_back(st);
  if (events_.stats)
    events_.stats({static_cast<double>(st.index), static_cast<double>(epoch_), st.reconMs, st.shadeMs, st.sampleMs,
                   st.compositeMs, st.totalMs(), static_cast<double>(st.fillInSlices),
                   static_cast<double>(st.dirtyBricks), static_cast<double>(st.dirtyVoxels),
                   static_cast<double>(st.shadedVoxels), static_cast<double>(st.dbufferPixels),
                   static_cast<double>(st.samples), static_cast<double>(st.raysComposited),
                   static_cast<double>(st.blocksComposited)});
  if (events_.frame) events_.frame(a, k);
  pending_ = true;
}

std::uint32_t LocalPipeline::control(std::uint32_t changes, const ViewState& next, bool lasting) {
  const serial::ViewStats vs = applyControl(*pipe_, changes, next, j_.pipeline.render, j_.grid);
  if ((changes & comm::ControlMsg::kView) && !lasting) orbitStats_.push_back(vs);
  pending_ = true;
  return ++epoch_;
}

void LocalPipeline::sync() {
  if (!pending_) return;
  pending_ = false;
  ++tally_.images;
  if (events_.image) events_.image(image());
}

ImageView LocalPipeline::image() const {
  const pp::TileImage& im = pipe_->image();
  return {&im.rgba, im.width, im.height, epoch_, static_cast<std::int64_t>(tally_.frames) - 1, true};
}

std::vector<float> LocalPipeline::composite(pp::CompositeMode mode) {
  return mode == pipe_->liveMode() ? pipe_->image().rgba : pipe_->compositeFull(mode).rgba;
}

bool LocalPipeline::requestVolume() {
  if (events_.volume) events_.volume(pipe_->reconstructor().output(), VolumeChange{});
  return true;
}

PipelineCounters LocalPipeline::counters() const {
  PipelineCounters c = tally_;
  latency_.recent(c);
  return c;
}

void LocalPipeline::streamEnded() {
  if (!census_) return;
  pipe_->setCensus(nullptr);
  census_->write(j_.census);
  spdlog::info("run: the census of {} frames is in {}", census_->frames(), j_.census);
}

std::string LocalPipeline::end(const RunEnd& e) {
  using FS = serial::FrameStats;
  std::printf("run: %llu frames through the serial pipeline in %.1f s\n", static_cast<unsigned long long>(tally_.frames),
              e.totalS);
  std::printf("  per frame (median): %.1f ms = reconstruct %.1f + shade %.1f + sample %.1f + composite %.1f\n",
              medianOf(frameStats_, [](const FS& s) { return s.totalMs(); }),
              medianOf(frameStats_, [](const FS& s) { return s.reconMs; }),
              medianOf(frameStats_, [](const FS& s) { return s.shadeMs; }),
              medianOf(frameStats_, [](const FS& s) { return s.sampleMs; }),
              medianOf(frameStats_, [](const FS& s) { return s.compositeMs; }));
  if (!e.orbitMs.empty()) {
    using VS = serial::ViewStats;
    std::printf("  full re-render after a view change (median of %zu): %.0f ms = lattice %.1f + cache reset %.1f + "
                "re-light %.1f + sample and put %.1f + composite %.1f\n",
                e.orbitMs.size(), median(e.orbitMs), medianOf(orbitStats_, [](const VS& s) { return s.latticeMs; }),
                medianOf(orbitStats_, [](const VS& s) { return s.cacheMs; }),
                medianOf(orbitStats_, [](const VS& s) { return s.shadeMs; }),
                medianOf(orbitStats_, [](const VS& s) { return s.sampleMs; }),
                medianOf(orbitStats_, [](const VS& s) { return s.compositeMs; }));
  }
  return "";
}

}  // namespace pp5::host
