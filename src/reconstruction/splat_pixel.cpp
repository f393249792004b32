// PLUS-compatible pixel splatting (nearest neighbour and trilinear) with
// MEAN / LATEST / MAXIMUM compounding, in PLUS's own arithmetic ("plus") or in
// exact float arithmetic ("float"). The PLUS behaviour reproduced here is
// specified in docs/notes/plus-reconstruction.md (sections cited as §n).
//
// Threads. For each frame the grid is cut into slabs along one axis, one slab
// per thread. Every thread walks the frame's pixels in the same row-major
// order but writes only the voxels of its own slab, so each voxel sees its
// updates in exactly the single-threaded order: any thread count gives the
// same bits (and, in "plus", PLUS's single-threaded result). A thread skips
// most pixels outside its slab by solving, per row, for the columns that can
// reach it; the exact ownership test is inside the kernels.
//
// Walking. Along a row every voxel coordinate is a monotonic step function of
// the column, so a run of pixels is cut into segments that share one voxel
// (nearest) or one lower corner (trilinear). A segment's update is gathered
// in registers and written once; PLUS's per-pixel arithmetic is applied pixel
// by pixel in registers. Segments are defined by the row alone, not by where
// a thread starts, so they are the same for every thread count.
//
// Incremental output. The kernels list each voxel they write once per frame
// (a one-byte flag per voxel says it is listed, so the list is appended to
// without a branch), with its brick. output() is recomputed at the listed
// voxels only, their bricks are the returned DirtyRegion, and hole filling
// then refreshes the holes near it.
#include "reconstruction/splat_pixel.hpp"

#include "reconstruction/slice_geometry.hpp"

#include <omp.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

#include <fmt/format.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.hpp"
#include "reconstruction/fan_mask.hpp"
#include "reconstruction/fixed_point.hpp"
#include "reconstruction/pixel_kernels.hpp"
#include "reconstruction/hole_fill.hpp"
#include "core/threads.hpp"

namespace pp5::gp {

namespace {

using namespace pixel;

// ---------------------------------------------------------------------------

struct PlusSource {
  const PlusCell* c;
  bool known(std::size_t i) const { return c[i].a != 0; }
  float value(std::size_t i) const { return c[i].v; }
  float weight(std::size_t i) const { return c[i].a * (1.0f / 256.0f); }
};
// Known voxels' output values are their unfilled values (only holes are ever
// filled), so the output itself is the source.
struct FloatSource {
  const FloatCell* c;
  const float* out;
  bool known(std::size_t i) const { return c[i].w > 0.0f; }
  float value(std::size_t i) const { return out[i]; }
  float weight(std::size_t i) const { return c[i].w; }
};

class PixelReconstructor final : public Reconstructor {
public:
  PixelReconstructor(const Grid& g, const ReconSettings& s) : Reconstructor(g, s) {
    // Settings built in code are held to the names a file could give.
    method_ = checkedEnum(s.method);
    PP5_CHECK(method_ != Method::Tent);
    comp_ = checkedEnum(s.pixel.compounding);
    plus_ = checkedEnum(s.arithmetic) == Arithmetic::Plus;
    PP5_CHECK(g.dims.x > 0 && g.dims.y > 0 && g.dims.z > 0);
    const std::size_t n = static_cast<std::size_t>(g.voxelCount());
    out_.allocate(g, ScalarType::F32);
    if (plus_)
      pcells_.assign(n, PlusCell{0, 0, 0});
    else
      fcells_.assign(n, FloatCell{0.0f, 0.0f});
    touched_.assign(n, 0);
    empty_ = DirtyRegion(g);
    bdims_ = empty_.brickDims();
    brickKnown_.assign(static_cast<std::size_t>(bdims_.x * bdims_.y * bdims_.z), 0);
    if (s.pixel.fillHoles) {
      filler_.emplace(s.pixel.holeFilling.empty() ? HoleFiller::defaultElements() : s.pixel.holeFilling, plus_);
      incrementalFill_ = s.pixel.fillHolesIncremental;
      filled_.assign(n, 0);
    }
    rejectBelow_ = s.pixelRejectionThreshold < 0.0
                       ? 0
                       : static_cast<int>(std::min(std::ceil(s.pixelRejectionThreshold), 65536.0));
  }

  InsertResult insert(const Frame& f, const Mat4& imageToReference, double timeS) override;
  void finish() override;
  // A window changes nothing here: every frame given to insert() is splatted
  // in full (exact inside any window), and no state links one frame to the
  // next, so an advanced frame needs nothing but its checks.
  void setWindow(const Box3& window) override {
    PP5_CHECK(!started_);
    Reconstructor::setWindow(window);
  }
  InsertResult advance(int width, int height, const Mat4& imageToReference, double timeS) override;
  void restorePrevious(const Frame& f) override {
    PP5_CHECK(advanced_.x > 0);  // right after advance()
    PP5_CHECK_EQ(f.width, advanced_.x);
    PP5_CHECK_EQ(f.height, advanced_.y);
    if (f.pixels.size() < f.byteSize())
      throw InputError(fmt::format("frame {}: {} bytes of pixels for a {}x{} image of {}-byte pixels", f.index,
                                   f.pixels.size(), f.width, f.height, bytesPerPixel(f.pixelType)));
    advanced_ = glm::ivec2(0);
  }
  const Volume& output() const override { return out_; }
  Volume weights() const override;
  bool covered(std::size_t i) const override { return plus_ ? pcells_[i].a != 0 : fcells_[i].w > 0.0f; }
  bool hasValue(std::size_t i) const override { return covered(i) || (!filled_.empty() && filled_[i]); }

private:
  float* out() { return reinterpret_cast<float*>(out_.bytes.data()); }
  int threadCount() const { return resolveThreads(settings_.threads); }
  // Threads worth starting for `work` units of `grain` each, at most `limit`.
  // The result never depends on it: slabs and bricks decide who writes what.
  static int worthwhile(int limit, std::uint64_t work, std::uint64_t grain) {
    return static_cast<int>(std::min<std::uint64_t>(static_cast<std::uint64_t>(limit), 1 + work / grain));
  }
  void splat(const Job& job, const Slab& slab, bool split, SlabOut& so);
  // Recomputes output() at the voxels the slab wrote and clears their flags.
  void updateOutput(SlabOut& so);
  void addBrickId(DirtyRegion& d, std::uint32_t id) const;
  // Refills the holes of `bricks` (sorted); sets changed[b] = 1 where an output value changed.
  void fillBricks(const std::vector<std::uint32_t>& bricks, int threads, std::vector<std::uint8_t>& changed);
  bool knownNear(std::uint32_t brick) const;

  Method method_ = Method::Nearest;
  Compounding comp_ = Compounding::Mean;
  bool plus_ = false;
  Volume out_;
  std::vector<PlusCell> pcells_;
  std::vector<FloatCell> fcells_;
  std::vector<std::uint8_t> touched_;     // voxels written since the last output update
  std::vector<std::uint8_t> brickKnown_;  // bricks that hold a covered voxel
  std::vector<std::uint8_t> filled_;      // holes that a hole-filling kernel filled (with a filler only)
  DirtyRegion empty_;
  Index3 bdims_{0};
  std::vector<SlabOut> slabOut_;
  int rejectBelow_ = 0;

  int maskW_ = -1, maskH_ = -1;
  std::vector<PixelRun> runs_;
  int maskX0_ = 0, maskX1_ = 0, maskY0_ = 0, maskY1_ = 0;  // the runs' bounding rectangle

  // The checks that insert() and advance() share, in insert()'s order (InputError naming `what`):
  // the frame's size; the transform; the pose's voxel map (into `map`), for frames with selected pixels.
  void checkSize(const std::string& what, int width, int height) const;
  void checkTransform(const std::string& what, const Mat4& imageToReference) const;
  void checkMap(const std::string& what, int width, int height, const Mat4& imageToReference, PixelMap& map) const;
  // The pixel runs of frames of this size (runs_ and their bounding rectangle).
  void selectRuns(int width, int height);

  bool started_ = false;            // a frame was inserted or advanced
  glm::ivec2 advanced_{0};          // the size of the frame just advanced (0 0: the last call was not advance())

  std::optional<HoleFiller> filler_;
  bool incrementalFill_ = false;
  bool filledOnce_ = false;  // finish() has filled the holes of the whole grid
};

void PixelReconstructor::splat(const Job& job, const Slab& slab, bool split, SlabOut& so) {
  if (plus_)
    splatPlus(method_, comp_, job, pcells_.data(), slab, split, so);
  else
    splatFloat(method_, comp_, job, fcells_.data(), slab, split, so);
}

void PixelReconstructor::checkSize(const std::string& what, int width, int height) const {
  if (width <= 0 || height <= 0)
    throw InputError(fmt::format("{}: the image is empty ({}x{} pixels)", what, width, height));
  if (width >= (1 << 24))  // keeps a row's 8-bit pixel sum exact in 32 bits and in float
    throw InputError(fmt::format("{}: {} pixels per row; at most 16777215 are supported", what, width));
}

void PixelReconstructor::checkTransform(const std::string& what, const Mat4& imageToReference) const {
  // Finite, affine, the image's axes not degenerate: what every method
  // requires of a pose (one rule, gp/slice_geometry).
  (void)poseFromMatrix(imageToReference, what);
}

void PixelReconstructor::checkMap(const std::string& what, int width, int height, const Mat4& imageToReference,
                                  PixelMap& map) const {
  // Voxel index of pixel (i, j): (ImageToReference * (i, j, 0, 1) - origin) / spacing,
  // with PLUS's association (entries times 1/spacing, §2).
  for (int a = 0; a < 3; ++a) {
    const double inv = 1.0 / grid_.spacing[a];
    map.X[a] = imageToReference[0][a] * inv;
    map.Y[a] = imageToReference[1][a] * inv;
    map.O[a] = imageToReference[3][a] * inv + (-grid_.origin[a] * inv);
  }
  // Every pixel's voxel coordinates lie between those of the frame's corners;
  // keeping them finite and below 2^50 keeps every conversion defined.
  for (int a = 0; a < 3; ++a)
    for (int ci = 0; ci < 4; ++ci) {
      const double p =
          map.O[a] + double(ci & 1 ? height - 1 : 0) * map.Y[a] + double(ci & 2 ? width - 1 : 0) * map.X[a];
      if (!(std::abs(p) < kPositionLimit))
        throw InputError(fmt::format("{}: the pose puts the image {:g} voxels from the grid", what, p));
    }
  if (plus_)
    for (int a = 0; a < 3; ++a)
      for (double v : {map.X[a], map.Y[a], map.O[a]})
        if (!(std::abs(v) < plusmath::kFixedLimit))
          throw InputError(fmt::format("{}: the pose puts the image {:.0f} voxels from the grid, beyond the "
                                       "range of PLUS's fixed-point arithmetic ({:.0f})",
                                       what, v, plusmath::kFixedLimit));
}

void PixelReconstructor::selectRuns(int width, int height) {
  if (width == maskW_ && height == maskH_) return;
  runs_ = pixelRuns(width, height, settings_);
  maskW_ = width;
  maskH_ = height;
  if (!runs_.empty()) {
    maskX0_ = runs_.front().x0;
    maskX1_ = runs_.front().x1;
    for (const PixelRun& r : runs_) {
      maskX0_ = std::min(maskX0_, r.x0);
      maskX1_ = std::max(maskX1_, r.x1);
    }
    maskY0_ = runs_.front().y;
    maskY1_ = runs_.back().y;
  }
}

InsertResult PixelReconstructor::advance(int width, int height, const Mat4& imageToReference, double timeS) {
  const std::string what = fmt::format("frame at t = {} s", timeS);
  checkSize(what, width, height);
  checkTransform(what, imageToReference);
  selectRuns(width, height);
  PixelMap map{};
  if (!runs_.empty()) checkMap(what, width, height, imageToReference, map);
  started_ = true;
  advanced_ = glm::ivec2(width, height);
  InsertResult res;
  res.dirty = empty_;
  return res;
}

InsertResult PixelReconstructor::insert(const Frame& f, const Mat4& imageToReference, double /*timeS*/) {
  const std::string what = fmt::format("frame {}", f.index);
  checkSize(what, f.width, f.height);
  if (f.pixels.size() < f.byteSize())
    throw InputError(fmt::format("{}: {} bytes of pixels for a {}x{} image of {}-byte pixels", what,
                                 f.pixels.size(), f.width, f.height, bytesPerPixel(f.pixelType)));
  checkTransform(what, imageToReference);
  if (plus_ && f.pixelType != PixelType::U8)
    throw InputError(fmt::format("{}: arithmetic \"plus\" reconstructs 8-bit frames only (PLUS's 8-bit "
                                 "volume); use arithmetic \"float\" for 16-bit frames",
                                 what));

  selectRuns(f.width, f.height);
  InsertResult res;
  res.dirty = empty_;
  Job job;
  if (!runs_.empty()) checkMap(what, f.width, f.height, imageToReference, job.map);
  started_ = true;
  advanced_ = glm::ivec2(0);
  if (runs_.empty()) return res;

  job.dims = grid_.dims;
  job.sy = grid_.dims.x;
  job.sz = grid_.dims.x * grid_.dims.y;
  job.runs = &runs_;
  job.width = f.width;
  job.u16 = f.pixelType == PixelType::U16;
  job.rejectBelow = rejectBelow_;
  job.touched = touched_.data();
  job.bx = bdims_.x;
  job.bxy = bdims_.x * bdims_.y;
  std::vector<std::uint8_t> swapped;
  job.pixels = f.pixels.data();
  if (job.u16 && std::endian::native != std::endian::little) {
    swapped.resize(f.byteSize());
    for (std::size_t i = 0; i + 1 < swapped.size(); i += 2) {
      const std::uint16_t v = static_cast<std::uint16_t>(f.pixels[i] | (f.pixels[i + 1] << 8));
      std::memcpy(&swapped[i], &v, 2);
    }
    job.pixels = swapped.data();
  }
  if (plus_) {
    for (int a = 0; a < 3; ++a) {
      job.fmap.X[a] = plusmath::toFixed(job.map.X[a]);
      job.fmap.Y[a] = plusmath::toFixed(job.map.Y[a]);
      job.fmap.O[a] = plusmath::toFixed(job.map.O[a]);
    }
  }

  // Slabs: cut the frame's footprint along the axis where it is longest.
  const int T = threadCount();
  std::vector<Slab> slabs(static_cast<std::size_t>(T));
  const bool split = T > 1;
  if (!split) {
    slabs[0] = {2, 0, grid_.dims.z};
  } else {
    const int xmin = maskX0_, xmax = maskX1_, ymin = maskY0_, ymax = maskY1_;
    double lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::numeric_limits<double>::infinity();
      hi[a] = -lo[a];
      for (int ci = 0; ci < 4; ++ci) {
        const double p =
            job.map.O[a] + double(ci & 1 ? ymax : ymin) * job.map.Y[a] + double(ci & 2 ? xmax : xmin) * job.map.X[a];
        lo[a] = std::min(lo[a], p);
        hi[a] = std::max(hi[a], p);
      }
      const double top = double(grid_.dims[a] - 1);
      lo[a] = std::clamp(std::floor(lo[a]), 0.0, top);
      hi[a] = std::clamp(std::ceil(hi[a]), 0.0, top);
    }
    int axis = 2;
    for (int a : {1, 0})
      if (hi[a] - lo[a] > hi[axis] - lo[axis]) axis = a;
    const auto first = static_cast<std::int64_t>(lo[axis]);
    const std::int64_t count = static_cast<std::int64_t>(hi[axis]) - first + 2;
    for (int t = 0; t < T; ++t) {
      slabs[t].axis = axis;
      slabs[t].lo = t == 0 ? 0 : first + count * t / T;
      slabs[t].hi = t == T - 1 ? grid_.dims[axis] : first + count * (t + 1) / T;
    }
  }

  if (slabOut_.size() < static_cast<std::size_t>(T)) slabOut_.resize(static_cast<std::size_t>(T));
  for (int t = 0; t < T; ++t) {  // (allocated here: nothing may throw inside the parallel region)
    SlabOut& so = slabOut_[t];
    so.prefix.resize(static_cast<std::size_t>(f.width) + 1);
    so.prefix32.resize(static_cast<std::size_t>(f.width) + 1);
    so.count.resize(static_cast<std::size_t>(f.width) + 1);
    so.marks.resize(static_cast<std::size_t>(f.width) + 32, 0);
    so.reserveWritten(static_cast<std::size_t>(f.width) * 8);
  }
  // Small frames are not worth waking threads for: the slabs stay the same,
  // fewer threads share them.
  std::uint64_t maskPixels = 0;
  for (const PixelRun& r : runs_) maskPixels += static_cast<std::uint64_t>(r.x1 - r.x0 + 1);
#pragma omp parallel num_threads(worthwhile(T, maskPixels, 32768))
  {
    const int nt = omp_get_num_threads(), tid = omp_get_thread_num();
    for (int t = tid; t < T; t += nt) {
      splat(job, slabs[t], split, slabOut_[t]);
      updateOutput(slabOut_[t]);
    }
  }
  // The bricks of the voxels written are the dirty region.
  std::vector<std::uint8_t> flags(brickKnown_.size(), 0);
  for (int t = 0; t < T; ++t) {
    SlabOut& so = slabOut_[t];
    res.pixelsInserted += so.pixels;
    so.pixels = 0;
    for (std::size_t k = 0; k < so.nWritten; ++k) {
      const std::uint32_t b = so.writtenBrick[k];
      flags[b] = 1;
      if (covered(static_cast<std::size_t>(so.written[k]))) brickKnown_[b] = 1;
    }
    so.nWritten = 0;
  }
#ifndef NDEBUG
  // Every flag must have been found and cleared (a missed brick would leave
  // its output stale).
  PP5_CHECK(std::find(touched_.begin(), touched_.end(), std::uint8_t{1}) == touched_.end());
#endif

  if (filler_ && (incrementalFill_ || filledOnce_)) {
    DirtyRegion d = empty_;
    for (std::size_t b = 0; b < flags.size(); ++b)
      if (flags[b]) addBrickId(d, static_cast<std::uint32_t>(b));
    if (!d.empty()) fillBricks(d.grown(filler_->reach()).bricks(), T, flags);
  }
  for (std::size_t b = 0; b < flags.size(); ++b)
    if (flags[b]) addBrickId(res.dirty, static_cast<std::uint32_t>(b));
  return res;
}

void PixelReconstructor::addBrickId(DirtyRegion& d, std::uint32_t id) const {
  const std::int64_t b = id;
  d.addBrick(b % bdims_.x, (b / bdims_.x) % bdims_.y, b / (bdims_.x * bdims_.y));
}

void PixelReconstructor::updateOutput(SlabOut& so) {
  float* o = out();
  for (std::size_t k = 0; k < so.nWritten; ++k) {
    const auto i = static_cast<std::size_t>(so.written[k]);
    touched_[i] = 0;
    if (plus_) {
      o[i] = pcells_[i].v;
    } else {
      const FloatCell c = fcells_[i];
      // One rounding: the exact sums divided once.
      o[i] = comp_ == Compounding::Mean ? (c.w > 0.0f ? c.s / c.w : 0.0f) : c.s;
    }
  }
}

bool PixelReconstructor::knownNear(std::uint32_t brick) const {
  const std::int64_t id = brick;
  const Index3 b(id % bdims_.x, (id / bdims_.x) % bdims_.y, id / (bdims_.x * bdims_.y));
  const std::int64_t r = (filler_->reach() + DirtyRegion::kDefaultBrick - 1) / DirtyRegion::kDefaultBrick;
  const Index3 lo = glm::max(b - Index3(r), Index3(0)), hi = glm::min(b + Index3(r), bdims_ - Index3(1));
  for (std::int64_t k = lo.z; k <= hi.z; ++k)
    for (std::int64_t j = lo.y; j <= hi.y; ++j)
      for (std::int64_t i = lo.x; i <= hi.x; ++i)
        if (brickKnown_[static_cast<std::size_t>((k * bdims_.y + j) * bdims_.x + i)]) return true;
  return false;
}

void PixelReconstructor::fillBricks(const std::vector<std::uint32_t>& bricks, int threads,
                                    std::vector<std::uint8_t>& changed) {
  float* o = out();
  const HoleFiller& filler = *filler_;
  const PlusSource psrc{pcells_.data()};
  const FloatSource fsrc{fcells_.data(), o};
  const Index3 dims = grid_.dims;
  const auto n = static_cast<std::int64_t>(bricks.size());
#pragma omp parallel for num_threads(worthwhile(threads, bricks.size(), 4)) schedule(dynamic, 1)
  for (std::int64_t k = 0; k < n; ++k) {
    const Box3 box = empty_.brickBox(bricks[k]);
    // With no covered voxel within reach every kernel fails: the holes are 0.
    const bool anyKnown = knownNear(bricks[k]);
    bool ch = false;
    for (std::int64_t z = box.lo.z; z < box.hi.z; ++z)
      for (std::int64_t y = box.lo.y; y < box.hi.y; ++y)
        for (std::int64_t x = box.lo.x; x < box.hi.x; ++x) {
          const std::size_t i = grid_.linear(x, y, z);
          if (covered(i)) continue;
          float v = 0.0f;
          const bool ok = anyKnown && (plus_ ? filler.tryFill(psrc, dims, x, y, z, v) : filler.tryFill(fsrc, dims, x, y, z, v));
          filled_[i] = ok;
          if (o[i] != v) {
            o[i] = v;
            ch = true;
          }
        }
    if (ch) changed[bricks[k]] = 1;
  }
}

void PixelReconstructor::finish() {
  // Incremental filling keeps the holes up to date after every frame.
  if (!filler_ || incrementalFill_) return;
  std::vector<std::uint32_t> all(brickKnown_.size());
  for (std::size_t b = 0; b < all.size(); ++b) all[b] = static_cast<std::uint32_t>(b);
  std::vector<std::uint8_t> changed(all.size(), 0);
  fillBricks(all, threadCount(), changed);
  filledOnce_ = true;
}

Volume PixelReconstructor::weights() const {
  Volume w;
  w.allocate(grid_, ScalarType::F32);
  float* p = reinterpret_cast<float*>(w.bytes.data());
  const std::size_t n = static_cast<std::size_t>(grid_.voxelCount());
  if (plus_)
    for (std::size_t i = 0; i < n; ++i) p[i] = pcells_[i].a * (1.0f / 256.0f);
  else
    for (std::size_t i = 0; i < n; ++i) p[i] = fcells_[i].w;
  return w;
}

}  // namespace

std::uint64_t pixelBytesPerVoxel(const ReconSettings& s) {
  // state + F32 output + one "written" flag (+ one "filled" flag)
  return (s.arithmetic == Arithmetic::Plus ? sizeof(PlusCell) : sizeof(FloatCell)) + 4 + 1 + (s.pixel.fillHoles ? 1 : 0);
}

std::unique_ptr<Reconstructor> makePixelReconstructor(const Grid& g, const ReconSettings& s) {
  return std::make_unique<PixelReconstructor>(g, s);
}

}  // namespace pp5::gp
