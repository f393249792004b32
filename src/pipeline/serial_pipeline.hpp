#pragma once
// The single-process pipeline: one graphics processor's update
// (rendering/gp_update.hpp) on the whole grid and screen, feeding one pixel
// processor's caches (rendering/tile_caches.hpp) that hold the whole image, frame by
// frame. The GP and PP ranks run the same two objects on their shares, so
// this is the reference that every distributed run is held to (design.md,
// "one serial reference").
//
// Per frame: reconstruct -> dirty bricks -> re-shade them (with the gradient
// margin) -> D-buffer of the boxes whose samples the new shades can change ->
// sample those lattice points -> put them in the ray cache -> recomposite the
// changed blocks and rays of the live mode.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/frame.hpp"
#include "core/render_settings.hpp"
#include "core/transfer_function.hpp"
#include "rendering/gp_update.hpp"
#include "reconstruction/reconstruction.hpp"
#include "rendering/shade_buffer.hpp"
#include "rendering/shading.hpp"
#include "rendering/ray_cache.hpp"
#include "rendering/tile_caches.hpp"
#include "pipeline/work_census.hpp"

namespace pp5::serial {

struct PipelineSettings {
  gp::ReconSettings recon;
  RenderSettings render;
  gp::ShadeSettings shading;
  TransferFunctionSettings tf;
  pp::RayCacheSettings cache;
};

// What one frame cost and touched (the stats file's row).
struct FrameStats {
  std::uint64_t index = 0;
  double reconMs = 0, shadeMs = 0, sampleMs = 0, compositeMs = 0;
  std::uint64_t dirtyBricks = 0, dirtyVoxels = 0;  // reconstruction's dirty region
  std::uint64_t shadedVoxels = 0;                   // re-shaded (dirty + gradient margin)
  std::uint64_t dbufferPixels = 0;                  // rays the D-buffer gave an interval
  std::uint64_t samples = 0;                        // lattice samples re-sampled
  std::uint64_t raysComposited = 0, blocksComposited = 0;
  int fillInSlices = 0;
  double totalMs() const { return reconMs + shadeMs + sampleMs + compositeMs; }
};

// Where a full re-render after a view change went (setCamera).
struct ViewStats {
  double latticeMs = 0, cacheMs = 0, shadeMs = 0, sampleMs = 0, compositeMs = 0;
  std::uint64_t samples = 0;  // visible samples put into the cache
  double totalMs() const { return latticeMs + cacheMs + shadeMs + sampleMs + compositeMs; }
};

class SerialPipeline {
public:
  // Refuses (InputError) a grid whose reconstruction and shade buffer do not fit in memory.
  SerialPipeline(const Grid& grid, const PipelineSettings& settings, std::uint64_t memoryLimitBytes = 0);
  // A volume read from a file, rendered like a reconstructed one; insert() refuses frames.
  SerialPipeline(const Volume& volume, const PipelineSettings& settings);

  FrameStats insert(const Frame& f, const Mat4& imageToReference, double timeS);
  // The reconstruction's final passes (e.g. hole filling at the end), then a
  // full re-shade and re-sample: what a view or shading change also does.
  void finish();

  // A new view: the lattice is rebuilt, everything re-shaded (a light at the
  // viewer moves with it) and re-sampled, and the live image recomposited.
  // The times: the lattice, the cache made empty for the new rays, the
  // re-lighting, sampling with the cache's puts (the sampling threads put
  // their own samples), compositing.
  ViewStats setCamera(const Camera& camera, double stepScale = 1.0, int pixelStride = 1);
  const Camera& camera() const { return gp_->camera(); }
  // New shading or transfer function: everything re-shaded and re-sampled.
  // With `live`, also a new live composition mode (one re-shade for both).
  void setStyle(const gp::ShadeSettings& shading, const TransferFunctionSettings& tf,
                std::optional<pp::CompositeMode> live = std::nullopt);
  // A new live composition mode: the cache recomposited in it; between
  // "over" and the grey-value modes (MIP, additive), shaded and sampled anew.
  void setLiveMode(pp::CompositeMode m);
  // render.value_window: the live image recomposited.
  void setValueWindow(double lo, double hi);

  // The live image (the first composition mode), maintained incrementally.
  const pp::TileImage& image() const { return cache().image(); }
  // A from-scratch render of the current grid in `mode`: shade everything,
  // sample every ray, composite in full. The reference the incremental image
  // must equal.
  pp::TileImage renderFromScratch(pp::CompositeMode mode) const;
  // The current cache composited in full in another mode.
  pp::TileImage compositeFull(pp::CompositeMode mode) const { return cache().compositeFull(mode); }

  const gp::Reconstructor& reconstructor() const { return gp_->reconstructor(); }
  const gp::ShadeBuffer& shadeBuffer() const { return gp_->shadeBuffer(); }
  const pp::RayCache& cache() const { return (*caches_)[0]; }
  const PipelineSettings& settings() const { return s_; }
  pp::CompositeMode liveMode() const { return live_; }
  // Counts each later frame's work into `census` (nullptr: stop); the
  // census must outlive its use. Its counting is not timed apart.
  void setCensus(WorkCensus* census) { census_ = census; }

private:
  PipelineSettings s_;
  Grid grid_;
  pp::CompositeMode live_ = pp::CompositeMode::Over;
  std::unique_ptr<gp::GpUpdate> gp_;
  std::unique_ptr<pp::TileCaches> caches_;  // one tile: the whole image
  std::uint64_t frames_ = 0;
  WorkCensus* census_ = nullptr;

  void init(std::unique_ptr<gp::Reconstructor> recon, std::uint64_t memoryLimitBytes);
  // The caches reset for the current camera's lattice (every sample transparent).
  void resetCaches();
  // Samples everything anew into the cache (cleared first unless `cleared`)
  // and composites; `st` gets the times of the two.
  void resample(bool cleared, ViewStats* st = nullptr);
};

}  // namespace pp5::serial
