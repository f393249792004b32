#pragma once
// One graphics processor's work, the per-frame sequence written once:
// reconstruct the frames, re-shade the voxels their changes reach (with the
// gradient margin), update the empty-space map, scan-convert into the
// D-buffer what the new shades can change, and ray-sample exactly that into a
// sink. A view or style change re-lights or re-shades and samples everything.
//
// The serial pipeline (serial/) runs it on the whole grid and screen; a GP
// rank (ranks/) runs it on its share, which a GpShare describes: the slab and
// tile partitionings (parallel/) each give one. Whatever the share, every
// sample it emits has the bits the whole-grid update computes.
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "core/camera.hpp"
#include "core/grid.hpp"
#include "core/render_settings.hpp"
#include "core/sample_lattice.hpp"
#include "core/transfer_function.hpp"
#include "rendering/change_tracker.hpp"
#include "rendering/dbuffer.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/empty_space.hpp"
#include "rendering/ray_sampler.hpp"
#include "reconstruction/reconstruction.hpp"
#include "rendering/shade_buffer.hpp"
#include "rendering/shading.hpp"

namespace pp5::gp {

// Which part of the shading and sampling one GP does.
class GpShare {
public:
  virtual ~GpShare() = default;
  // Of the voxels whose shade a change needs (shadingBoxes of the dirty
  // region), those this GP shades, under `camera`.
  virtual std::vector<Box3> shadeShare(const std::vector<Box3>& needed, const Camera& camera) const = 0;
  // What a full re-shade shades under `camera`.
  virtual std::vector<Box3> shadeAll(const Camera& camera) const = 0;
  // When this GP shades one box whatever changed (shadeShare is `needed`
  // clipped to it): that box. nullopt: the share depends on the change.
  virtual std::optional<Box3> shadeRegion() const { return std::nullopt; }
  // After a view change alone (every opacity as it was): the region whose
  // visible voxels get new light, the empty-space map kept. nullopt: shade
  // everything anew (shadeAll) and rebuild the map.
  virtual std::optional<Box3> relightRegion() const = 0;
  // The samples this GP takes.
  virtual const SamplerOptions& sampler() const = 0;
};

// The whole grid and screen: the serial pipeline's share.
class WholeShare final : public GpShare {
public:
  explicit WholeShare(const Grid& grid) : whole_{Index3(0), grid.dims} {}
  std::vector<Box3> shadeShare(const std::vector<Box3>& needed, const Camera&) const override { return needed; }
  std::vector<Box3> shadeAll(const Camera&) const override { return {whole_}; }
  std::optional<Box3> shadeRegion() const override { return whole_; }
  std::optional<Box3> relightRegion() const override { return whole_; }
  const SamplerOptions& sampler() const override { return options_; }

private:
  Box3 whole_;
  SamplerOptions options_;
};

struct GpUpdateSettings {
  ReconSettings recon;
  RenderSettings render;  // render.threads: the shading and sampling threads
  ShadeSettings shading;  // its threads are render.threads
  TransferFunctionSettings tf;
  std::uint64_t memoryLimitBytes = 0;  // 0: what the machine has
};

class GpUpdate {
public:
  // The empty grid, shaded under `camera` (nothing to sample yet: every
  // sample of an empty grid is transparent). InputError when the
  // reconstruction and the shade buffer do not fit in memory.
  // `recon`: a reconstructor made elsewhere (e.g. gp/stored_volume), else one
  // made from settings.recon.
  GpUpdate(const Grid& grid, const GpUpdateSettings& settings, const Camera& camera, std::unique_ptr<GpShare> share,
           std::unique_ptr<Reconstructor> recon = nullptr);

  Reconstructor& reconstructor() { return *recon_; }
  const Reconstructor& reconstructor() const { return *recon_; }

  // Re-shades the voxels of this GP's share whose shade `dirty`'s changes
  // can have changed (ChangeTracker) and updates the empty-space map; false
  // when no shade changed (nothing to sample). `changedRuns`: the
  // InsertResults' changedRuns since the last call (used when the
  // reconstructor reports them).
  bool shadeChanged(const DirtyRegion& dirty, std::span<const RowRun> changedRuns);
  // Every lattice sample whose cell holds a voxel the last shadeChanged()
  // changed, into `sink` (transparent ones too, but those both maps know
  // were and stay 0).
  void sampleChanged(SampleSink& sink);
  // The row runs the last shadeChanged() shaded, and the D-buffer of the
  // last sampleChanged() (for statistics).
  const std::vector<Box3>& lastShaded() const { return shaded_; }
  const DBuffer& dbuffer() const { return dbuf_; }

  // A new camera: the lattice is rebuilt. Call resampleAll() after it.
  // stepScale: the lattice's step times this (render.step_scale: a coarser view while the user drags).
  void setCamera(const Camera& camera, double stepScale = 1.0, int pixelStride = 1);
  // New shading or transfer function. Call resampleAll() after it.
  void setStyle(const ShadeSettings& shading, const TransferFunctionSettings& tf);
  // A new live composition mode: what reshadeAll and the sampler make next
  // (grey values for MIP and additive, classified colour for over).
  void setLiveMode(CompositeMode m);
  // Re-shades everything this GP shades and rebuilds the empty-space map;
  // viewOnly: only the view changed, so where the share allows, only the
  // visible voxels get new light and the map stays.
  void reshadeAll(bool viewOnly);
  // Every visible sample of this GP's share into `sink` (a receiving cache
  // was cleared: transparent samples are not sent).
  void sampleAll(SampleSink& sink);
  // reshadeAll(viewOnly), then sampleAll(sink).
  void resampleAll(bool viewOnly, SampleSink& sink) {
    reshadeAll(viewOnly);
    sampleAll(sink);
  }

  const Grid& grid() const { return grid_; }
  const Camera& camera() const { return camera_; }
  const SampleLattice& lattice() const { return lattice_; }
  const ShadeBuffer& shadeBuffer() const { return shade_; }
  const EmptySpaceMap& emptySpace() const { return space_; }
  const ChangeTracker& changeTracker() const { return changes_; }
  const TransferFunction& transferFunction() const { return tf_; }
  const GpUpdateSettings& settings() const { return s_; }
  const GpShare& share() const { return *share_; }

private:
  Grid grid_;
  GpUpdateSettings s_;
  std::unique_ptr<GpShare> share_;
  std::unique_ptr<Reconstructor> recon_;
  TransferFunction tf_;
  Camera camera_;
  SampleLattice lattice_;
  ShadeBuffer shade_;
  EmptySpaceMap space_;
  EmptySpaceMap spaceBefore_;  // space_ before the last shadeChanged()
  ChangeTracker changes_;
  std::vector<Box3> shaded_;  // the runs the last shadeChanged() shaded
  std::vector<std::int64_t> changedVoxels_;
  DBuffer dbuf_;
};

}  // namespace pp5::gp
