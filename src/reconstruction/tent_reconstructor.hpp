#pragma once
// The tent reconstructor's class (reconstruction/splat_tent.cpp, the 1990 paper's
// method), shared by the two files that define it: splat_tent.cpp (the
// kernel's sums, fill-in, the stream of frames) and tent_replacement.cpp (the
// replacement of aging data). Internal to them; the rest of the program makes
// one with makeTentReconstructor (reconstruction/splat_tent.hpp). The voxel update and the
// row loop are here, inline, because the kernel's voxel loops run them.
#include <algorithm>
#include <limits>
#include <bit>
#include <climits>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "core/frame.hpp"
#include "reconstruction/dirty_region.hpp"
#include "reconstruction/fan_mask.hpp"
#include "reconstruction/reconstruction.hpp"
#include "reconstruction/slice_geometry.hpp"
#include "reconstruction/tent_kernel.hpp"
#include "reconstruction/voxel_array.hpp"

namespace pp5::gp::tent {

enum class Along { Any, ConstV, ConstUV };

// One run of voxels (i0..j, k) to (i1, j, k) along x inside a slice's support slab.
struct Row {
  std::int64_t j, k, i0, i1;
  std::size_t offset;  // into the contribution scratch (motion vectors)
};

// Open interval of real i where lo < a + i*d < hi, intersected into [ilo, ihi]
// (invD = 1/d, 0 when d is 0).
inline void clipInterval(double a, double d, double invD, double lo, double hi, double& ilo, double& ihi) {
  if (invD == 0.0) {
    if (!(a > lo && a < hi)) {
      ilo = 1.0;
      ihi = 0.0;
    }
    return;
  }
  double t0 = (lo - a) * invD, t1 = (hi - a) * invD;
  if (d < 0.0) std::swap(t0, t1);
  ilo = std::max(ilo, t0);
  ihi = std::min(ihi, t1);
}

// Slice coordinates (U, V, N) of voxel (0,0,0) and their change per step
// along each grid axis.
struct SliceFrame {
  Vec3 base;
  Vec3 step[3];
};

// A row's first and last changed x and the largest value given, kept while
// its voxels are updated (a NaN counts as infinity).
struct ChangedRange {
  std::int32_t lo = INT32_MAX, hi = -1;
  float max = -std::numeric_limits<float>::infinity();
  void add(std::int64_t i, float value) {
    lo = std::min(lo, static_cast<std::int32_t>(i));
    hi = static_cast<std::int32_t>(i);
    if (!(value <= max)) max = std::isnan(value) ? std::numeric_limits<float>::infinity() : value;
  }
};

// -------------------------------------------------------- reconstructor --
//
// Replacement of aging data:
//  - accumulate: sum(w*v) and sum(w) only grow; value = sum(w*v)/sum(w).
//  - motion_vector (the paper's): each cell of motionVectorBrick^3 voxels
//    remembers the direction of motion of the last slice that wrote it (the
//    frame's centre minus the centre at the last direction update, taken once
//    the centre has moved by he/2, so jitter does not flip it; frames after a
//    jump, and the first frame, have no direction until they move). When a
//    slice whose direction is more than 90 degrees from the cell's brings data
//    to the cell, the cell is "rebased" once, before the slice is added: each
//    voxel's current value and weight move to a base layer and its sums
//    restart. From then on the voxel's value is
//        (1 - w_new) * base + w_new * (new sum(w*v) / new sum(w))
//    (w_new = motionVectorNewWeight), and its weight is new sum(w) / w_new,
//    the weight of a plain mean in which the old data has a share of 1-w_new.
//    Rebasing keeps each voxel's value and weight bit for bit, so only voxels
//    where new data lands change, and a back-and-forth rescan in the same
//    direction never rebases (it accumulates). The decision uses only the
//    cell's state and the slice, so it does not depend on the thread count.
//  - decay: each voxel keeps the time of its last update; when new data
//    arrives at time t, its sums are first multiplied by exp(-(t - t_last)/tau).
//    The value stays sum(w*v)/sum(w), so a voxel that gets no new data does
//    not change; when a region is rescanned, the old data's share fades with
//    the time since it was written (after 3 tau it weighs exp(-3) of what it
//    did). weights() shows the weight as of the voxel's last update (decayed
//    then). Times that go backwards do not decay.
class TentReconstructor final : public Reconstructor {
public:
  TentReconstructor(const Grid& g, const ReconSettings& s);

  InsertResult insert(const Frame& f, const Mat4& imageToReference, double timeS) override;
  void setWindow(const Box3& window) override;
  InsertResult advance(int width, int height, const Mat4& imageToReference, double timeS) override;
  void restorePrevious(const Frame& f) override;
  bool reportsChangedRuns() const override { return true; }
  const Volume& output() const override { return output_; }
  Volume weights() const override;
  bool covered(std::size_t i) const override { return weightAt(i) > 0.0f; }

private:
  // The checks on a frame's time and pose that insert() and advance() share (InputError naming `what`).
  SlicePose checkPose(const std::string& what, const Mat4& imageToReference, double timeS) const;
  // The pixel runs of frames of this size (runs_, runsBox_).
  void selectRuns(int width, int height);
  // The stream state that every frame advances, inserted or not: the time origin, and the jump test and
  // direction of motion against the previous frame. Returns whether the frame jumped (no fill-in), and the
  // largest displacement of a corner of the pixel rectangle since the previous frame.
  bool stepMotion(const SlicePose& pose, double timeS, double& maxCornerMm);
  void endFrame(const SlicePose& pose, double timeS, bool pixelsKnown);
  // Splats one slice: its support slab into `dirty`, the rows whose output changed onto `changed`.
  void splat(const SlicePose& pose, const SliceImage& img, double timeS, const Vec3& dir, DirtyRegion& dirty,
             std::vector<RowRun>& changed);
  SliceKernel sliceKernel(const SlicePose& pose, const SliceImage& img);
  void buildProfiles(const SliceImage& img, const KnotLattice& lat, int padRows);
  template <class Sums>
  void contributeAlong(const Sums& sums, const SliceFrame& sf, float tf);
  template <class Sums, Along A>
  void contribute(const Sums& sums, const SliceFrame& sf, float tf);
  template <class Sums, Along A, Replacement R>
  void contributeRows(const Sums& sums, const SliceFrame& sf, std::size_t first, std::size_t end, float tf);
  void visitOrder(const SliceFrame& sf);
  void rebaseCells(const Vec3& dir);
  void applyStored(float tf);
  template <typename F>
  void forRows(F&& f);

  float outputAt(std::size_t i) const;
  // The output volume's voxels as floats (F32, little-endian like the host).
  float* outF32() { return reinterpret_cast<float*>(output_.bytes.data()); }
  float weightAt(std::size_t i) const;
  // Returns whether the voxel's output bits changed.
  template <Replacement R>
  bool applyVoxel(float* acc, float* out, std::size_t i, float cw, float cwv, float tf, float& cacheT,
                  float& cacheF);
  // Appends the rows of rows_ whose output changed (rowChanged_) to `runs`.
  void collectChanged(std::vector<RowRun>& runs) const;

  Replacement mode_;
  int threads_;
  double hl_, ha_, he_;
  float wNew_ = 0.8f, wOld_ = 0.2f;

  Volume output_;
  // sum(w*v) and sum(w) side by side, so a voxel costs one cache line, not two.
  VoxelArray<float> acc_;
  std::vector<float> tLast_;          // decay: time of the last update, s since the first frame
  std::vector<float> baseV_, baseW_;  // motion_vector: the rebased value and weight
  Index3 cellDims_{0};
  std::vector<glm::vec3> cellDir_;  // motion_vector: 0 = no direction yet
  std::vector<std::uint32_t> cellStamp_;
  std::uint32_t sliceCounter_ = 0;

  // Scratch, reused from slice to slice.
  std::vector<Row> rows_;
  std::vector<std::size_t> order_;  // the order contributeRows visits rows_ in
  // Per row of rows_, the first and last x whose output bits the slice changed (first > last: none),
  // and the largest value they were given.
  std::vector<ChangedRange> rowChanged_;
  std::vector<float> contrib_;  // motion_vector: (cw, cwv) per voxel of rows_
  std::vector<std::uint32_t> touched_;
  std::vector<float> profiles_, rowOff_;  // the slice's lateral profiles and axial offsets (SliceKernel)
  SliceImage cur_, prev_, mid_;
  std::vector<PixelRun> runs_;  // pixels selected in frames of runsWidth_ x runsHeight_
  int runsWidth_ = -1, runsHeight_ = -1;
  glm::ivec4 runsBox_{0};       // their bounding box: x0 y0 x1 y1

  // Stream state.
  bool started_ = false;     // a frame was inserted or advanced
  bool hasPrev_ = false;
  bool prevPixels_ = false;  // prev_ holds the previous frame's pixels (not so after advance())
  bool lastAdvanced_ = false;  // the last frame went to advance(): restorePrevious() may follow
  SlicePose prevPose_;
  double prevTime_ = 0.0;
  bool saidTimeOrder_ = false;  // a timestamp that did not advance was said (once)
  bool hasT0_ = false;
  double t0_ = 0.0;
  Vec3 anchor_{0.0};
  Vec3 dir_{0.0};
};

// Adds one voxel's contribution from the current slice and refreshes its output.
template <Replacement R>
inline bool TentReconstructor::applyVoxel(float* acc, float* out, std::size_t i, float cw, float cwv, float tf,
                                          float& cacheT, float& cacheF) {
  float* a = acc + 2 * i;
  float swv = a[0], sw = a[1];
  if constexpr (R == Replacement::Decay) {
    const float tl = tLast_[i];
    if (sw > 0.0f && tf > tl) {
      // Neighbouring voxels were usually last written by the same slice.
      if (!(tl == cacheT)) {
        cacheT = tl;
        cacheF = static_cast<float>(
            std::exp(-(static_cast<double>(tf) - static_cast<double>(tl)) / settings_.tent.decayTauS));
      }
      sw *= cacheF;
      swv *= cacheF;
    }
    tLast_[i] = std::max(tl, tf);
  }
  sw += cw;
  swv += cwv;
  a[0] = swv;
  a[1] = sw;
  float value = swv / sw;
  if constexpr (R == Replacement::MotionVector)
    if (baseW_[i] > 0.0f) value = wOld_ * baseV_[i] + wNew_ * value;
  const bool changed = std::bit_cast<std::uint32_t>(out[i]) != std::bit_cast<std::uint32_t>(value);
  out[i] = value;
  return changed;
}


// Runs f(first, end) over ranges of rows_, on threads_ threads. Each row is a disjoint
// set of voxels and each voxel's update depends only on its own state and the
// slice, so any split of the rows gives the same bits.
template <typename F>
void TentReconstructor::forRows(F&& f) {
  const auto nrows = static_cast<std::int64_t>(rows_.size());
  constexpr std::int64_t kChunk = 64;
  const std::int64_t chunks = (nrows + kChunk - 1) / kChunk;
  if (threads_ <= 1 || chunks < 2) {
    f(std::size_t{0}, static_cast<std::size_t>(nrows));
    return;
  }
#pragma omp parallel for num_threads(threads_) schedule(dynamic, 1)
  for (std::int64_t c = 0; c < chunks; ++c)
    f(static_cast<std::size_t>(c * kChunk), static_cast<std::size_t>(std::min(nrows, (c + 1) * kChunk)));
}

}  // namespace pp5::gp::tent
