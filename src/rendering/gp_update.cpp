#include "rendering/gp_update.hpp"

#include "rendering/stencil.hpp"

namespace pp5::gp {

GpUpdate::GpUpdate(const Grid& grid, const GpUpdateSettings& settings, const Camera& camera,
                   std::unique_ptr<GpShare> share, std::unique_ptr<Reconstructor> recon)
    : grid_(grid), s_(settings), share_(std::move(share)), recon_(std::move(recon)), tf_(settings.tf), camera_(camera) {
  s_.shading.threads = s_.render.threads;
  s_.shading.greyValues = compositesGreyValues(s_.render.compositing.front());
  // The reconstruction, then the shade buffer (4 bytes a voxel) on top of it.
  if (!recon_) recon_ = makeReconstructor(grid_, s_.recon, s_.memoryLimitBytes, "reconstruction grid ([grid])");
  checkGridFits(grid_, 4, "shade buffer ([grid])", s_.memoryLimitBytes);
  shade_ = ShadeBuffer(grid_);
  const bool compare = !recon_->reportsChangedRuns();
  checkGridFits(grid_, ChangeTracker::bytesPerVoxel(recon_->output().type, compare), "change tracker ([grid])",
                s_.memoryLimitBytes);
  changes_ = ChangeTracker(recon_->output(), shade_, compare);
  lattice_ = SampleLattice(camera_, grid_, s_.render.step(grid_), s_.render.maxSamples, s_.render.threads,
                           s_.render.pixelStride);
  reshadeAll(false);
}

bool GpUpdate::shadeChanged(const DirtyRegion& dirty, std::span<const RowRun> changedRuns) {
  // The dirty bricks and their gradient margin (what shade(dirty) shades)
  // bound the work; within them the tracker finds the voxels whose shade can
  // change, and from their new shades the voxels, cells and bricks that the
  // empty-space map, the D-buffer and the sampler then limit themselves to.
  // With the changes reported and a share of one box, the tracker visits
  // the rows next to the changes in that box, and the shading boxes are not
  // worked out.
  const TransferFunction* tf = s_.shading.greyValues ? nullptr : &tf_;
  const std::optional<Box3> region = share_->shadeRegion();
  if (!changes_.compares() && region) {
    shaded_ = changes_.shadingRuns(recon_->output(), changedRuns, *region, tf);
  } else {
    const std::vector<Box3> needed = shadingBoxes(dirty);
    const std::vector<Box3> within = share_->shadeShare(needed, camera_);
    shaded_ = changes_.compares() ? changes_.shadingRuns(recon_->output(), needed, within, tf)
                                  : changes_.shadingRuns(recon_->output(), changedRuns, within, tf);
  }
  changedVoxels_.clear();
  shade(recon_->output(), tf_, s_.shading, camera_, shaded_, shade_, &changedVoxels_);
  changes_.setShadeChanges(changedVoxels_, shade_);
  spaceBefore_.assignBricks(space_);  // a few kB (a byte per 8^3 cells); the storage is kept
  space_.update(shade_, changes_.changedRuns());
  return changes_.changedShades() > 0;
}

void GpUpdate::sampleChanged(SampleSink& sink) {
  dbuf_.build(camera_, stencilBoxes(changes_.changedBricks()));
  sampleRegion(shade_, lattice_, dbuf_, s_.render, sink, &space_, share_->sampler(), &spaceBefore_,
               changes_.changedCells());
}

void GpUpdate::setCamera(const Camera& camera, double stepScale, int pixelStride) {
  camera_ = camera;
  s_.render.stepScale = stepScale;
  s_.render.pixelStride = pixelStride;
  lattice_ = SampleLattice(camera_, grid_, s_.render.step(grid_), s_.render.maxSamples, s_.render.threads, pixelStride);
}

void GpUpdate::setStyle(const ShadeSettings& shading, const TransferFunctionSettings& tf) {
  s_.shading = shading;
  s_.shading.threads = s_.render.threads;
  s_.tf = tf;
  s_.shading.greyValues = compositesGreyValues(s_.render.compositing.front());
  tf_ = TransferFunction(tf);
}

void GpUpdate::setLiveMode(CompositeMode m) {
  std::erase(s_.render.compositing, m);
  s_.render.compositing.insert(s_.render.compositing.begin(), m);
  s_.shading.greyValues = compositesGreyValues(m);
}

void GpUpdate::reshadeAll(bool viewOnly) {
  const std::optional<Box3> relight = viewOnly ? share_->relightRegion() : std::nullopt;
  if (relight) {
    // The values and the style are as they were, so every voxel's opacity is
    // too: only the voxels that were visible need new light, and the
    // empty-space map (opacity only) stays as it is.
    shade(recon_->output(), tf_, s_.shading, camera_, space_.visibleVoxelBoxes(*relight), shade_);
    return;
  }
  shade(recon_->output(), tf_, s_.shading, camera_, share_->shadeAll(camera_), shade_);
  space_ = EmptySpaceMap(shade_, s_.render.threads);
  changes_.resync(recon_->output(), shade_);
}

void GpUpdate::sampleAll(SampleSink& sink) {
  gp::sampleAll(shade_, lattice_, s_.render, sink, &space_, share_->sampler());
}

}  // namespace pp5::gp
