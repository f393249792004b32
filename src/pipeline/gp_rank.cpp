#include "pipeline/gp_rank.hpp"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <memory>
#include <numeric>
#include <optional>
#include <thread>

#include <fmt/format.h>

#include "core/error.hpp"
#include "formats/sample_runs.hpp"
#include "rendering/gp_update.hpp"
#include "rendering/ray_sampler.hpp"
#include "pipeline/partition.hpp"
#include "pipeline/rank_stats.hpp"

namespace pp5::ranks {

namespace {

using namespace pp5::comm;
using namespace pp5::gp;
using namespace pp5::parallel;

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
  // Appends tile `tile`'s samples to `out` in their wire form and empties
  // its buckets.
  void drain(int tile, SampleWire wire, std::vector<std::byte>& out) {
    for (auto& t : buf_) {
      auto& v = t[static_cast<std::size_t>(tile)];
      encodeSampleRuns(v, wire, out);
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
    gp::GpUpdateSettings us;
    us.recon = c_.recon;
    us.recon.threads = c_.parallel.threads;
    us.render = c_.render;
    us.render.threads = c_.parallel.threads;
    us.shading = c_.shading;
    us.shading.threads = us.render.threads;
    us.tf = c_.tf;
    us.memoryLimitBytes = c_.memoryLimitBytes;
    state_ = makeControlState(us.render, us.shading, c_.tf);

    tiles_ = TileGrid(us.render.width, us.render.height, c_.parallel.tileSize);
    const TileOwnership own = c_.parallel.ownership();
    ppOfTile_.resize(static_cast<std::size_t>(tiles_.count()));
    for (int i = 0; i < tiles_.count(); ++i)
      ppOfTile_[static_cast<std::size_t>(i)] = c_.layout.ppRank(tileOwner(i, tiles_.count(), c_.layout.pps, own));
    partition_ = makePartition(c_.parallel, c_.layout, c_.grid, us.recon, tiles_);
    // As the serial pipeline starts: the empty grid shaded (and nothing to
    // sample: every sample of an empty grid is transparent).
    update_ = std::make_unique<gp::GpUpdate>(c_.grid, us, controlCamera(state_, c_.render, c_.grid),
                                             partition_->share(g_));
    if (const auto w = partition_->window(g_)) update_->reconstructor().setWindow(*w);
    const int threads = std::max<int>(us.render.threads, static_cast<int>(std::thread::hardware_concurrency())) + 1;
    buckets_ = std::make_unique<TileBuckets>(workTileOwners(tiles_), tiles_.count(), threads);
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
        case kTagKeepAlive: {
          EmptyMsg alive;
          alive.h = {kTagAlive, h.epoch, h.frame};
          t_.send(0, alive);
          break;
        }
        case kTagQuit: {
          const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
          const std::uint64_t mem =
              update_->reconstructor().output().bytes.size() * 2 + update_->shadeBuffer().memoryBytes() +
              update_->changeTracker().memoryBytes();
          t_.send(0, makeReport(t_, Role::Gp, clock_.total(), wall, 0, mem, streamCpu_));
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
  StreamCpu streamCpu_;  // the stream of frames' CPU (cost model)
  std::uint32_t epoch_ = 0;

  ControlState state_;
  TileGrid tiles_;
  std::vector<int> ppOfTile_;
  std::unique_ptr<Partition> partition_;
  std::unique_ptr<gp::GpUpdate> update_;
  std::unique_ptr<TileBuckets> buckets_;

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
    streamCpu_.begin(t_);
    std::vector<Header> frames;
    std::vector<std::uint64_t> dirtyOf;
    std::vector<StageTimes> times;
    DirtyRegion dirty;
    std::vector<RowRun> changedRuns;
    bool anyDirty = false;
    auto add = [&](const Message& m) {
      InsertResult r = reconstruct(m);
      frames.push_back(m.header());
      dirtyOf.push_back(r.dirty.voxelCount());
      times.push_back(clock_.take());
      changedRuns.insert(changedRuns.end(), r.changedRuns.begin(), r.changedRuns.end());
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
    // A volume snapshot asked for right behind these frames holds them, and
    // shading and sampling do not change the grid: it goes before them, so
    // that the host has it a frame's shading and sampling sooner.
    if (!held_) held_ = t_.poll();
    if (held_ && held_->source == 0 && held_->tag == kTagVolumeRequest) {
      sendVolume(held_->header());
      held_.reset();
    }
    const Header& last = frames.back();

    std::uint64_t samples = 0;
    bool shaded = false;
    // Runs can come without a dirty brick (a windowed reconstruction's
    // changes in its reach outside the window): the tracker takes them too.
    if (anyDirty || !changedRuns.empty()) {
      clock_.start(kShade);
      shaded = update_->shadeChanged(dirty, changedRuns);
    }
    if (shaded) {
      clock_.start(kSample);
      update_->sampleChanged(*buckets_);
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
    streamCpu_.end(t_);
  }

  // One frame's reconstruction.
  InsertResult reconstruct(const Message& m) {
    clock_.start(kReceive);
    const FrameMsg& fm = m.as<FrameMsg>();
    epoch_ = fm.h.epoch;
    std::array<double, 16> rm;
    std::copy(std::begin(fm.imageToReference), std::end(fm.imageToReference), rm.begin());
    const Mat4 pose = fromRowMajor(rm);
    InsertResult r;
    if (fm.poseOnly) {
      if (!m.payload<FrameMsg>().empty()) throw CommError("a pose-only frame message carries pixels");
      clock_.start(kReconstruct);
      r = update_->reconstructor().advance(fm.width, fm.height, pose, fm.timeS);
    } else {
      const Frame f = unpackFrame(m, fm.width, fm.height, fm.pixelType, fm.sourceIndex, fm.timeS, m.payload<FrameMsg>());
      clock_.start(kReconstruct);
      r = update_->reconstructor().insert(f, pose, fm.timeS);
    }
    clock_.stop();
    if (!r.dirty.empty()) {
      if (sinceVolume_.bricks().empty() && sinceVolume_.grid().dims != r.dirty.grid().dims) sinceVolume_ = DirtyRegion(r.dirty.grid(), r.dirty.brickSize());
      sinceVolume_.merge(r.dirty);
    }
    return r;
  }

  void onPrevious(const Message& m) {
    clock_.start(kReceive);
    const PreviousMsg& pm = m.as<PreviousMsg>();
    const Frame f = unpackFrame(m, pm.width, pm.height, pm.pixelType, pm.h.frame, 0.0, m.payload<PreviousMsg>());
    clock_.start(kReconstruct);
    update_->reconstructor().restorePrevious(f);
    clock_.stop();
  }

  void onControl(const Message& m) {
    const ControlMsg& cm = m.as<ControlMsg>();
    epoch_ = cm.h.epoch;
    const std::uint32_t ch = cm.changes;
    state_ = cm.state;
    // The parts of the settings a control state does not carry stay as they were.
    RenderSettings r = update_->settings().render;
    ShadeSettings shading = update_->settings().shading;
    TransferFunctionSettings tfs;
    applyControlState(state_, r, shading, tfs);
    if (ch & ControlMsg::kMode) update_->setLiveMode(liveMode(state_));
    if (ch & (ControlMsg::kShading | ControlMsg::kTransfer)) update_->setStyle(shading, tfs);
    if (ch & ControlMsg::kView) update_->setCamera(controlCamera(state_, c_.render, c_.grid), state_.stepScale, state_.pixelStride);
    if (ch & ControlMsg::kFinish) {
      clock_.start(kReconstruct);
      update_->reconstructor().finish();
      volumeWhole_ = true;
    }
    std::uint64_t samples = 0;
    const std::uint64_t bytes0 = t_.totals().bytesSent;
    if (ch & ControlMsg::kResample) {
      // What the serial pipeline's setCamera or setStyle does, for this GP's
      // share: a view change alone re-lights where the share allows.
      clock_.start(kShade);
      update_->reshadeAll(!(ch & ControlMsg::kReshade));
      clock_.start(kSample);
      update_->sampleAll(*buckets_);
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
      std::vector<std::byte> buf(sizeof sm);
      std::memcpy(buf.data(), &sm, sizeof sm);
      buckets_->drain(tile, c_.wire, buf);
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

  // This GP's part of the volume: whole the first time and after the final
  // passes (which change voxels no frame's dirty region names), then only the
  // runs of bricks along x that frames changed since the last request (the
  // host keeps the volume it assembled). The boxes go together, in as few
  // messages of at most 64 MiB as they fit in (one for a few frames'
  // changes: a message each took the host a loop turn), a box too large for
  // one split into runs of z planes.
  void sendVolume(const Header& h) {
    constexpr std::size_t kMessageBytes = std::size_t{64} << 20;
    const Box3 part = partition_->volumePart(g_);
    const Volume& v = update_->reconstructor().output();
    const auto bpv = static_cast<std::size_t>(scalarBytes(v.type));
    std::vector<Box3> boxes;
    auto add = [&](const Box3& b) {
      const std::size_t planeBytes = static_cast<std::size_t>((b.hi.x - b.lo.x) * (b.hi.y - b.lo.y)) * bpv;
      const std::int64_t planes = std::max<std::int64_t>(1, static_cast<std::int64_t>(kMessageBytes / planeBytes));
      for (std::int64_t z = b.lo.z; z < b.hi.z; z += planes)
        boxes.push_back(Box3{Index3(b.lo.x, b.lo.y, z), Index3(b.hi.x, b.hi.y, std::min(b.hi.z, z + planes))});
    };
    if (volumeWhole_) {
      if (!part.empty()) add(part);
    } else if (!part.empty()) {
      const Index3 bd = sinceVolume_.brickDims();
      const auto& ids = sinceVolume_.bricks();
      for (std::size_t i = 0; i < ids.size();) {
        std::size_t e = i + 1;
        while (e < ids.size() && ids[e] == ids[e - 1] + 1 && ids[e] % bd.x != 0) ++e;  // one row of bricks
        Box3 b = sinceVolume_.brickBox(ids[i]);
        b.hi = sinceVolume_.brickBox(ids[e - 1]).hi;
        b.lo = glm::max(b.lo, part.lo);
        b.hi = glm::min(b.hi, part.hi);
        if (!b.empty()) add(b);
        i = e;
      }
    }
    volumeWhole_ = false;
    sinceVolume_.clear();
    const Grid& g = c_.grid;
    std::size_t next = 0;
    do {  // at least one message: the last says this GP is done
      std::size_t end = next, bytes = 0;
      while (end < boxes.size() && (end == next || bytes + boxes[end].voxelCount() * bpv <= kMessageBytes))
        bytes += boxes[end++].voxelCount() * bpv;
      VolumeMsg vm;
      vm.h = {kTagVolume, h.epoch, h.frame};
      vm.gp = static_cast<std::uint32_t>(g_);
      vm.scalarType = static_cast<std::uint32_t>(v.type);
      vm.boxes = static_cast<std::uint32_t>(end - next);
      vm.last = end == boxes.size();
      std::vector<std::byte> buf(sizeof vm + (end - next) * sizeof(VolumeBox) + bytes);
      std::memcpy(buf.data(), &vm, sizeof vm);
      std::byte* out = buf.data() + sizeof vm;
      for (std::size_t i = next; i < end; ++i, out += sizeof(VolumeBox)) {
        VolumeBox vb;
        for (int a = 0; a < 3; ++a) vb.lo[a] = boxes[i].lo[a], vb.hi[a] = boxes[i].hi[a];
        std::memcpy(out, &vb, sizeof vb);
      }
      for (std::size_t i = next; i < end; ++i) {
        const Box3& box = boxes[i];
        const auto rowBytes = static_cast<std::size_t>(box.hi.x - box.lo.x) * bpv;
        for (std::int64_t k = box.lo.z; k < box.hi.z; ++k)
          for (std::int64_t j = box.lo.y; j < box.hi.y; ++j, out += rowBytes)
            std::memcpy(out, v.bytes.data() + g.linear(box.lo.x, j, k) * bpv, rowBytes);
      }
      t_.sendBuffer(0, kTagVolume, std::move(buf));
      next = end;
    } while (next < boxes.size());
  }

  // The bricks frames changed since the last volume request; whether the
  // next sends the whole part instead.
  DirtyRegion sinceVolume_;
  bool volumeWhole_ = true;
};

}  // namespace

void runGpRank(comm::Transport& t, const GpRankConfig& c) { parallel::runRank<GpRank>(t, c); }

}  // namespace pp5::ranks
