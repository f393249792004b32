#include "ranks/gp_rank.hpp"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <memory>
#include <numeric>
#include <optional>
#include <thread>

#include <fmt/format.h>

#include "parallel/rank_stats.hpp"
#include "core/error.hpp"
#include "gp/dbuffer.hpp"
#include "gp/ray_sampler.hpp"
#include "core/sample_lattice.hpp"
#include "gp/shade_buffer.hpp"

namespace pp5::ranks {

namespace {

using namespace pp5::comm;
using namespace pp5::gp;
using namespace pp5::parallel;

Box3 wholeGrid(const Grid& g) { return {Index3(0), g.dims}; }

// Buckets the sampler's batches by PP tile, one set of buckets per sampling
// thread (consume() is called concurrently), to be sent once sampling is done.
class TileBuckets final : public SampleSink {
public:
  TileBuckets(std::vector<std::uint32_t> workToTile, int tiles, int threads)
      : workToTile_(std::move(workToTile)),
        buf_(static_cast<std::size_t>(threads), std::vector<std::vector<RaySample>>(static_cast<std::size_t>(tiles))) {}
  void consume(int thread, std::uint32_t workTile, std::span<const RaySample> s) override {
    PP5_CHECK_LT(static_cast<std::size_t>(thread), buf_.size());
    auto& v = buf_[static_cast<std::size_t>(thread)][workToTile_[workTile]];
    v.insert(v.end(), s.begin(), s.end());
  }
  std::uint64_t count(int tile) const {
    std::uint64_t n = 0;
    for (const auto& t : buf_) n += t[static_cast<std::size_t>(tile)].size();
    return n;
  }
  // Appends tile `tile`'s samples to `out` and empties its buckets.
  void drain(int tile, std::byte* out) {
    for (auto& t : buf_) {
      auto& v = t[static_cast<std::size_t>(tile)];
      if (!v.empty()) std::memcpy(out, v.data(), v.size() * sizeof(RaySample));
      out += v.size() * sizeof(RaySample);
      // A full view's buckets are large; keep small ones for the next frame.
      if (v.capacity() > (std::size_t{1} << 20)) std::vector<RaySample>().swap(v);
      else v.clear();
    }
  }

private:
  std::vector<std::uint32_t> workToTile_;
  std::vector<std::vector<std::vector<RaySample>>> buf_;
};

class GpRank {
public:
  GpRank(Transport& t, const GpRankConfig& c)
      : t_(t), c_(c), g_(c.layout.gpIndex(t.rank())), start_(std::chrono::steady_clock::now()) {
    const Grid& grid = c_.grid;
    ReconSettings rs = c_.recon;
    rs.threads = c_.parallel.threads;
    render_ = c_.render;
    render_.threads = c_.parallel.threads;
    shading_ = c_.shading;
    shading_.threads = render_.threads;
    tf_ = TransferFunction(c_.tf);
    state_ = makeControlState(render_, shading_, c_.tf);
    recon_ = makeReconstructor(grid, rs, c_.memoryLimitBytes, "reconstruction grid ([grid])");
    checkGridFits(grid, 4, "shade buffer ([grid])", c_.memoryLimitBytes);
    shade_ = ShadeBuffer(grid);

    tiles_ = TileGrid(render_.width, render_.height, c_.parallel.tileSize);
    const TileOwnership own = c_.parallel.ownership();
    ppOfTile_.resize(static_cast<std::size_t>(tiles_.count()));
    for (int i = 0; i < tiles_.count(); ++i)
      ppOfTile_[static_cast<std::size_t>(i)] = c_.layout.ppRank(tileOwner(i, tiles_.count(), c_.layout.pps, own));
    workTile_ = std::gcd(32, c_.parallel.tileSize);
    const int wcols = (render_.width + workTile_ - 1) / workTile_, wrows = (render_.height + workTile_ - 1) / workTile_;
    std::vector<std::uint32_t> workToTile(static_cast<std::size_t>(wcols) * static_cast<std::size_t>(wrows));
    for (int wy = 0; wy < wrows; ++wy)
      for (int wx = 0; wx < wcols; ++wx)
        workToTile[static_cast<std::size_t>(wy * wcols + wx)] = static_cast<std::uint32_t>(
            tiles_.tileOfPixel(static_cast<std::uint32_t>(wy * workTile_ * render_.width + wx * workTile_)));

    slab_ = c_.parallel.slab();
    if (slab_) {
      slabs_ = SlabLayout(grid, c_.layout.gps, c_.parallel.split());
      owned_ = slabs_.ownedCells(g_);
      if (!owned_.empty()) {
        window_ = slabs_.window(g_, c_.parallel.ghostVoxels);
        shadeRegion_ = Box3{owned_.lo, owned_.hi + Index3(1)}.intersect(wholeGrid(grid));
      }
      recon_->setWindow(window_);
      options_.ownedCells = owned_;
    } else {
      for (int i : tilesOwnedBy(g_, tiles_.count(), c_.layout.gps, own)) myRects_.push_back(tiles_.rect(i));
      options_.workTiles.assign(workToTile.size(), 0);
      for (std::size_t w = 0; w < workToTile.size(); ++w)
        options_.workTiles[w] = tileOwner(static_cast<int>(workToTile[w]), tiles_.count(), c_.layout.gps, own) == g_;
    }
    options_.tileSize = workTile_;
    const int threads = std::max<int>(render_.threads, static_cast<int>(std::thread::hardware_concurrency())) + 1;
    buckets_ = std::make_unique<TileBuckets>(std::move(workToTile), tiles_.count(), threads);

    camera_ = controlCamera(state_, c_.render, grid);
    lattice_ = SampleLattice(camera_, grid, render_.step(grid), render_.maxSamples, render_.threads);
    // As the serial pipeline starts: the empty grid shaded (and nothing to
    // sample: every sample of an empty grid is transparent).
    shadeAll();
    space_ = EmptySpaceMap(shade_, render_.threads);
  }

  void run() {
    for (;;) {
      Message m = next();
      const Header& h = m.header();
      if (m.source != 0) throw CommError(fmt::format("unexpected message (tag {}) from rank {}", m.tag, m.source));
      switch (m.tag) {
        case kTagFrame: onFrames(m); break;
        case kTagPrevious: onPrevious(m); break;
        case kTagControl: onControl(m); break;
        case kTagVolumeRequest: sendVolume(h); break;
        case kTagQuit: {
          const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
          const std::uint64_t mem = recon_->output().bytes.size() * 2 + shade_.memoryBytes();
          t_.send(0, makeReport(t_, Role::Gp, clock_.total(), wall, 0, mem));
          t_.flush();
          return;
        }
        default: throw CommError(fmt::format("unexpected message tag {} from the host", m.tag));
      }
    }
  }

private:
  Transport& t_;
  GpRankConfig c_;
  // A message polled while gathering a batch of frames that was not one of
  // them: handled next.
  std::optional<Message> held_;
  int g_;
  std::chrono::steady_clock::time_point start_;
  StageClock clock_;
  std::uint32_t epoch_ = 0;
  std::uint64_t lastFrame_ = 0;

  std::unique_ptr<Reconstructor> recon_;
  RenderSettings render_;
  ShadeSettings shading_;
  TransferFunction tf_;
  ControlState state_;
  Camera camera_;
  SampleLattice lattice_;
  ShadeBuffer shade_;
  EmptySpaceMap space_, spaceBefore_;
  DBuffer dbuf_;

  TileGrid tiles_;
  std::vector<int> ppOfTile_;
  int workTile_ = 32;
  SamplerOptions options_;
  std::unique_ptr<TileBuckets> buckets_;

  bool slab_ = true;
  SlabLayout slabs_;
  Box3 owned_, window_, shadeRegion_;
  std::vector<TileRect> myRects_;

  // tile: whether a sample in one of this GP's tiles can read a voxel of `b`.
  bool visible(const Box3& b) const {
    const Grid& g = c_.grid;
    // The samples that read voxels of b lie in the cells [lo - 1, hi), i.e.
    // at voxel positions [lo - 1, hi] (clamped to the sampling box).
    const Vec3 lo = glm::max(Vec3(b.lo) - 1.0, Vec3(0.0)) - kStencilSlackVoxels;
    const Vec3 hi = glm::min(Vec3(b.hi), Vec3(g.dims - Index3(1))) + kStencilSlackVoxels;
    double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
    for (int a = 0; a < 8; ++a) {
      const Vec3 v((a & 1) ? hi.x : lo.x, (a & 2) ? hi.y : lo.y, (a & 4) ? hi.z : lo.z);
      const auto p = camera_.project(g.voxelToWorld(v));
      if (!p) return true;  // reaches behind the eye: keep it
      x0 = std::min(x0, p->px);
      x1 = std::max(x1, p->px);
      y0 = std::min(y0, p->py);
      y1 = std::max(y1, p->py);
    }
    // Pixel x's ray passes through x + 0.5; one pixel of margin for rounding.
    const double px0 = std::ceil(x0 - 0.5) - 1, px1 = std::floor(x1 - 0.5) + 1;
    const double py0 = std::ceil(y0 - 0.5) - 1, py1 = std::floor(y1 - 0.5) + 1;
    for (const TileRect& r : myRects_)
      if (px1 >= r.x0 && px0 < r.x0 + r.width && py1 >= r.y0 && py0 < r.y0 + r.height) return true;
    return false;
  }

  // The part of the serial pipeline's shading boxes this GP shades.
  std::vector<Box3> myShare(const std::vector<Box3>& boxes) const {
    std::vector<Box3> out;
    for (const Box3& b : boxes) {
      if (slab_) {
        const Box3 c = b.intersect(shadeRegion_);
        if (!c.empty()) out.push_back(c);
      } else {
        // A frame's shading boxes span the whole slice; cut them into bricks
        // so that what this GP's tiles do not see is really skipped.
        constexpr std::int64_t B = 16;
        const Box3 c = b.intersect(wholeGrid(c_.grid));
        for (std::int64_t k = c.lo.z; k < c.hi.z; k += B)
          for (std::int64_t j = c.lo.y; j < c.hi.y; j += B)
            for (std::int64_t i = c.lo.x; i < c.hi.x; i += B) {
              const Box3 brick{Index3(i, j, k), glm::min(Index3(i, j, k) + Index3(B), c.hi)};
              if (visible(brick)) out.push_back(brick);
            }
      }
    }
    return out;
  }

  void shadeAll() {
    if (slab_) {
      if (!shadeRegion_.empty()) shade(recon_->output(), tf_, shading_, camera_, shadeRegion_, shade_);
      return;
    }
    // Bricks, so that what none of this GP's tiles sees is skipped.
    constexpr std::int64_t B = 32;
    const Index3 d = c_.grid.dims;
    std::vector<Box3> seen;
    for (std::int64_t k = 0; k < d.z; k += B)
      for (std::int64_t j = 0; j < d.y; j += B)
        for (std::int64_t i = 0; i < d.x; i += B) {
          const Box3 b{Index3(i, j, k), glm::min(Index3(i, j, k) + Index3(B), d)};
          if (visible(b)) seen.push_back(b);
        }
    shade(recon_->output(), tf_, shading_, camera_, seen, shade_);
  }

  Frame unpackFrame(const Message& m, int width, int height, std::uint8_t type, std::uint64_t index, double timeS,
                    std::span<const std::byte> payload) {
    Frame f;
    if (type > static_cast<std::uint8_t>(PixelType::U16))
      throw CommError(fmt::format("frame {}: unknown pixel type {} in the host's message", index, type));
    f.width = width;
    f.height = height;
    f.pixelType = static_cast<PixelType>(type);
    f.index = index;
    f.timestamp = timeS;
    if (width <= 0 || height <= 0 || payload.size() != f.byteSize())
      throw CommError(fmt::format("frame {}: the host's message holds {} pixel bytes for a {}x{} image (tag {})", index,
                                  payload.size(), width, height, m.tag));
    f.pixels.resize(payload.size());
    std::memcpy(f.pixels.data(), payload.data(), payload.size());
    return f;
  }

  // The held message, or the next from the network (the time waited for it
  // counted as waiting).
  Message next() {
    if (held_) {
      Message m = std::move(*held_);
      held_.reset();
      return m;
    }
    const double w0 = t_.waitSeconds();
    Message m = t_.wait(fmt::format("the host's next frame (GP {})", g_ + 1));
    clock_.add(kWait, 1e3 * (t_.waitSeconds() - w0));
    return m;
  }

  // A frame, and in tick mode the frames already waiting behind it (up to
  // parallel.batch_frames): each is reconstructed in order, then shading,
  // sampling and the samples sent cover the union of their dirty regions
  // once. The grid, the shade buffer and the cache end up as after one
  // update per frame (a lattice point re-sampled twice keeps its last value,
  // and one transparent before and after the batch was and stays 0), at a
  // fraction of the cost when the frames overlap, which lets a GP that fell
  // behind catch up. Lockstep keeps one update per frame, as its images are
  // compared frame by frame. Each frame gets its own credit, with its own
  // reconstruction time; the batch's shading, sampling and samples are
  // counted on its last frame.
  void onFrames(const Message& first) {
    std::vector<Header> frames;
    std::vector<std::uint64_t> dirtyOf;
    std::vector<StageTimes> times;
    DirtyRegion dirty;
    bool anyDirty = false;
    auto add = [&](const Message& m) {
      InsertResult r = reconstruct(m);
      frames.push_back(m.header());
      dirtyOf.push_back(r.dirty.voxelCount());
      times.push_back(clock_.take());
      if (r.dirty.empty()) return;
      if (anyDirty) {
        dirty.merge(r.dirty);
      } else {
        dirty = std::move(r.dirty);
        anyDirty = true;
      }
    };
    add(first);
    if (!c_.parallel.lockstep())
      while (frames.size() < static_cast<std::size_t>(c_.parallel.batchFrames)) {
        std::optional<Message> n = t_.poll();
        if (!n) break;
        const bool same = n->source == 0 && n->header().epoch == epoch_;
        if (same && n->tag == kTagFrame) {
          add(*n);
        } else if (same && n->tag == kTagPrevious) {
          onPrevious(*n);
        } else {
          held_ = std::move(n);
          break;
        }
      }
    const Header& last = frames.back();

    std::uint64_t samples = 0;
    std::vector<Box3> all, mine;
    if (anyDirty) {
      clock_.start(kShade);
      all = shadingBoxes(dirty);
      mine = myShare(all);
      shade(recon_->output(), tf_, shading_, camera_, mine, shade_);
      spaceBefore_ = space_;
      space_.update(shade_, mine);
    }
    if (!mine.empty()) {
      clock_.start(kSample);
      // slab: only this GP's cells' samples can change; tile: the serial
      // pipeline's few merged boxes (the work-tile mask keeps the rays to this
      // GP's tiles, whose samples read only voxels of visible bricks).
      dbuf_.build(camera_, stencilBoxes(c_.grid, slab_ ? mine : all));
      sampleRegion(shade_, lattice_, dbuf_, render_, *buckets_, &space_, options_, &spaceBefore_);
    }
    const std::uint64_t bytes0 = t_.totals().bytesSent;
    clock_.start(kSend);
    samples = sendSamples(last, false);
    const std::uint64_t bytes = t_.totals().bytesSent - bytes0;
    const StageTimes update = clock_.take();
    const auto n = static_cast<std::uint32_t>(frames.size());
    for (std::size_t i = 0; i + 1 < frames.size(); ++i) credit(frames[i], false, 0, 0, dirtyOf[i], times[i], n);
    StageTimes t = times.back();
    for (int st = 0; st < kStageCount; ++st) t.ms[st] += update.ms[st];
    credit(last, false, samples, bytes, dirtyOf.back(), t, n);
  }

  // One frame's reconstruction.
  InsertResult reconstruct(const Message& m) {
    clock_.start(kReceive);
    const FrameMsg& fm = m.as<FrameMsg>();
    epoch_ = fm.h.epoch;
    lastFrame_ = fm.h.frame;
    std::array<double, 16> rm;
    std::copy(std::begin(fm.imageToReference), std::end(fm.imageToReference), rm.begin());
    const Mat4 pose = fromRowMajor(rm);
    InsertResult r;
    if (fm.poseOnly) {
      if (!m.payload<FrameMsg>().empty()) throw CommError("a pose-only frame message carries pixels");
      clock_.start(kReconstruct);
      r = recon_->advance(fm.width, fm.height, pose, fm.timeS);
    } else {
      const Frame f = unpackFrame(m, fm.width, fm.height, fm.pixelType, fm.sourceIndex, fm.timeS, m.payload<FrameMsg>());
      clock_.start(kReconstruct);
      r = recon_->insert(f, pose, fm.timeS);
    }
    clock_.stop();
    return r;
  }

  void onPrevious(const Message& m) {
    clock_.start(kReceive);
    const PreviousMsg& pm = m.as<PreviousMsg>();
    const Frame f = unpackFrame(m, pm.width, pm.height, pm.pixelType, pm.h.frame, 0.0, m.payload<PreviousMsg>());
    clock_.start(kReconstruct);
    recon_->restorePrevious(f);
    clock_.stop();
  }

  void onControl(const Message& m) {
    const ControlMsg& cm = m.as<ControlMsg>();
    epoch_ = cm.h.epoch;
    const std::uint32_t ch = cm.changes;
    state_ = cm.state;
    RenderSettings r = render_;
    TransferFunctionSettings tfs;
    applyControlState(state_, r, shading_, tfs);
    shading_.threads = render_.threads;
    if (ch & (ControlMsg::kShading | ControlMsg::kTransfer)) tf_ = TransferFunction(tfs);
    if (ch & ControlMsg::kView) {
      camera_ = controlCamera(state_, c_.render, c_.grid);
      lattice_ = SampleLattice(camera_, c_.grid, render_.step(c_.grid), render_.maxSamples, render_.threads);
    }
    if (ch & ControlMsg::kFinish) {
      clock_.start(kReconstruct);
      recon_->finish();
    }
    std::uint64_t samples = 0;
    const std::uint64_t bytes0 = t_.totals().bytesSent;
    if (ch & ControlMsg::kResample) {
      // What the serial pipeline's setCamera or resampleAll does, for this
      // GP's share.
      clock_.start(kShade);
      if (slab_ && !(ch & ControlMsg::kReshade)) {
        // Only the view changed, so every voxel's opacity is as it was: the
        // visible voxels of this GP's region get new light, and the
        // empty-space map stays. (A tile GP has shaded only what its tiles
        // saw under the old view, so it shades the new view's bricks anew.)
        shade(recon_->output(), tf_, shading_, camera_, space_.visibleVoxelBoxes(shadeRegion_), shade_);
      } else {
        shadeAll();
        space_ = EmptySpaceMap(shade_, render_.threads);
      }
      clock_.start(kSample);
      sampleAll(shade_, lattice_, render_, *buckets_, &space_, options_);
      clock_.start(kSend);
      samples = sendSamples(cm.h, true);
    }
    credit(cm.h, true, samples, t_.totals().bytesSent - bytes0, 0);
  }

  // Sends the buckets, one message per PP tile, then one GpDone to every PP.
  std::uint64_t sendSamples(const Header& of, bool full) {
    const int P = c_.layout.pps;
    std::vector<std::uint32_t> batches(static_cast<std::size_t>(P), 0);
    std::vector<std::uint64_t> perPp(static_cast<std::size_t>(P), 0);
    std::uint64_t total = 0;
    for (int tile = 0; tile < tiles_.count(); ++tile) {
      const std::uint64_t n = buckets_->count(tile);
      if (n == 0) continue;
      SamplesMsg sm;
      sm.h = {kTagSamples, of.epoch, of.frame};
      sm.gp = static_cast<std::uint32_t>(g_);
      sm.tile = static_cast<std::uint32_t>(tile);
      sm.count = n;
      std::vector<std::byte> buf(sizeof sm + n * sizeof(RaySample));
      std::memcpy(buf.data(), &sm, sizeof sm);
      buckets_->drain(tile, buf.data() + sizeof sm);
      const int dest = ppOfTile_[static_cast<std::size_t>(tile)];
      t_.sendBuffer(dest, kTagSamples, std::move(buf));
      ++batches[static_cast<std::size_t>(c_.layout.ppIndex(dest))];
      perPp[static_cast<std::size_t>(c_.layout.ppIndex(dest))] += n;
      total += n;
    }
    for (int p = 0; p < P; ++p) {
      GpDoneMsg d;
      d.h = {kTagGpDone, of.epoch, of.frame};
      d.gp = static_cast<std::uint32_t>(g_);
      d.batches = batches[static_cast<std::size_t>(p)];
      d.samples = perPp[static_cast<std::size_t>(p)];
      d.full = full ? 1 : 0;
      t_.send(c_.layout.ppRank(p), d);
    }
    return total;
  }

  void credit(const Header& of, bool control, std::uint64_t samples, std::uint64_t bytes, std::uint64_t dirtyVoxels) {
    credit(of, control, samples, bytes, dirtyVoxels, clock_.take(), 1);
  }
  void credit(const Header& of, bool control, std::uint64_t samples, std::uint64_t bytes, std::uint64_t dirtyVoxels,
              const StageTimes& times, std::uint32_t batch) {
    CreditMsg cr;
    cr.h = {kTagCredit, of.epoch, of.frame};
    cr.gp = static_cast<std::uint32_t>(g_);
    cr.isControl = control ? 1 : 0;
    cr.batch = batch;
    cr.times = times;
    cr.samples = samples;
    cr.bytesSent = bytes;
    cr.dirtyVoxels = dirtyVoxels;
    t_.send(0, cr);
  }

  // This GP's part of the reconstructed volume, in runs of z planes.
  void sendVolume(const Header& h) {
    const Grid& g = c_.grid;
    Box3 box;
    if (slab_) {
      if (!owned_.empty()) {
        // Cells [lo, hi) own voxels [lo, hi); the grid's last voxel plane
        // goes with the last cell.
        box = owned_;
        for (int a = 0; a < 3; ++a)
          if (box.hi[a] == g.dims[a] - 1) box.hi[a] = g.dims[a];
      }
    } else if (g_ == 0) {
      box = wholeGrid(g);
    }
    const Volume& v = recon_->output();
    const auto bpv = static_cast<std::size_t>(scalarBytes(v.type));
    const std::int64_t nx = box.hi.x - box.lo.x, ny = box.hi.y - box.lo.y;
    const std::size_t planeBytes = static_cast<std::size_t>(std::max<std::int64_t>(0, nx * ny)) * bpv;
    const std::int64_t planesPerMsg =
        planeBytes ? std::max<std::int64_t>(1, static_cast<std::int64_t>((std::size_t{64} << 20) / planeBytes)) : 1;
    std::int64_t z = box.lo.z;
    do {
      const std::int64_t z1 = box.empty() ? z : std::min(box.hi.z, z + planesPerMsg);
      VolumeMsg vm;
      vm.h = {kTagVolume, h.epoch, h.frame};
      vm.gp = static_cast<std::uint32_t>(g_);
      vm.scalarType = static_cast<std::uint32_t>(v.type);
      vm.lo[0] = box.lo.x, vm.lo[1] = box.lo.y, vm.lo[2] = z;
      vm.hi[0] = box.hi.x, vm.hi[1] = box.hi.y, vm.hi[2] = z1;
      vm.last = z1 >= box.hi.z || box.empty();
      std::vector<std::byte> buf(sizeof vm + planeBytes * static_cast<std::size_t>(std::max<std::int64_t>(0, z1 - z)));
      std::memcpy(buf.data(), &vm, sizeof vm);
      std::byte* out = buf.data() + sizeof vm;
      for (std::int64_t k = z; k < z1; ++k)
        for (std::int64_t j = box.lo.y; j < box.hi.y; ++j) {
          std::memcpy(out, v.bytes.data() + g.linear(box.lo.x, j, k) * bpv, static_cast<std::size_t>(nx) * bpv);
          out += static_cast<std::size_t>(nx) * bpv;
        }
      t_.sendBuffer(0, kTagVolume, std::move(buf));
      z = z1;
      if (vm.last) break;
    } while (true);
  }
};

}  // namespace

void runGpRank(comm::Transport& t, const GpRankConfig& c) {
  GpRank gp(t, c);
  t.barrier();  // ready: the host starts acquiring once every rank is
  gp.run();
}

}  // namespace pp5::ranks
