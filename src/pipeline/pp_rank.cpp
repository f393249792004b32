#include "pipeline/pp_rank.hpp"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <deque>
#include <memory>
#include <thread>

#include <fmt/format.h>

#include "pipeline/rank_stats.hpp"
#include "core/error.hpp"
#include "formats/sample_runs.hpp"
#include "core/sample_lattice.hpp"
#include "rendering/tile_caches.hpp"

namespace pp5::ranks {

namespace {

using namespace pp5::comm;
using namespace pp5::pp;
using namespace pp5::parallel;
using Clock = std::chrono::steady_clock;

class PpRank {
public:
  PpRank(Transport& t, const PpRankConfig& c)
      : t_(t), c_(c), p_(c.layout.ppIndex(t.rank())), start_(Clock::now()), queues_(static_cast<std::size_t>(c.layout.gps)),
        lastDone_(static_cast<std::size_t>(c.layout.gps), -1) {
    render_ = c_.render;
    render_.threads = c_.parallel.threads;
    state_ = makeControlState(render_, c_.shading, c_.tf);
    tiles_ = TileGrid(render_.width, render_.height, c_.parallel.tileSize);
    mine_ = tilesOwnedBy(p_, tiles_.count(), c_.layout.pps, c_.parallel.ownership());
    slot_.assign(static_cast<std::size_t>(tiles_.count()), -1);
    std::vector<TileRect> rects;
    for (std::size_t i = 0; i < mine_.size(); ++i) {
      slot_[static_cast<std::size_t>(mine_[i])] = static_cast<int>(i);
      rects.push_back(tiles_.rect(mine_[i]));
    }
    caches_ = std::make_unique<TileCaches>(rects, render_.width, c_.cache, render_.threads);
    spare_ = std::make_unique<TileCaches>(rects, render_.width, c_.cache, render_.threads);
    prepare(state_);
    swapCaches();
  }

  void run() {
    const bool lockstep = c_.parallel.lockstep();
    const auto tick = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / c_.parallel.tickHz));
    auto nextTick = Clock::now() + tick;
    auto lastHeard = Clock::now();
    comm::IdleBackoff idle;
    for (;;) {
      std::optional<Message> m;
      if (lockstep) {
        const double w0 = t_.waitSeconds();
        m = t_.wait(fmt::format("samples or a command (PP {})", p_ + 1));
        clock_.add(kWait, 1e3 * (t_.waitSeconds() - w0));
      } else {
        m = t_.poll();
        if (!m) {
          const auto now = Clock::now();
          if (now >= nextTick) {
            onTick();
            nextTick = std::max(nextTick + tick, now);
          } else {
            const auto idle0 = Clock::now();
            idle.pause(std::chrono::duration_cast<std::chrono::microseconds>(nextTick - now));
            clock_.add(kWait, std::chrono::duration<double, std::milli>(Clock::now() - idle0).count());
          }
          if (std::chrono::duration<double>(now - lastHeard).count() > t_.timeoutS())
            throw CommError(fmt::format("no message in {:.0f} s while waiting for samples or a command (PP {}); a "
                                        "rank may have died or hung (parallel.timeout_s)",
                                        t_.timeoutS(), p_ + 1));
          continue;
        }
        lastHeard = Clock::now();
        idle.reset();
      }
      if (m->source == 0) {
        switch (m->tag) {
          case kTagControl:
            if (lockstep) onControl(m->as<ControlMsg>());
            else pending_.push_back(m->as<ControlMsg>());
            break;
          case kTagRequest: onRequest(m->as<RequestMsg>()); break;
          case kTagKeepAlive: {
            EmptyMsg alive;
            alive.h = {kTagAlive, m->header().epoch, m->header().frame};
            t_.send(0, alive);
            break;
          }
          case kTagQuit: {
            const double wall = std::chrono::duration<double>(Clock::now() - start_).count();
            const std::uint64_t mem = caches_->memoryBytes() + spare_->memoryBytes();
            t_.send(0, makeReport(t_, Role::Pp, clock_.total(), wall, dropped_, mem, streamCpu_));
            t_.flush();
            return;
          }
          default: throw CommError(fmt::format("unexpected message tag {} from the host", m->tag));
        }
      } else {
        const Role r = c_.layout.role(m->source);
        if (r != Role::Gp || (m->tag != kTagSamples && m->tag != kTagGpDone))
          throw CommError(fmt::format("unexpected message (tag {}) from rank {}", m->tag, m->source));
        queues_[static_cast<std::size_t>(c_.layout.gpIndex(m->source))].push_back(std::move(*m));
      }
      if (lockstep) {
        applyComplete();
      } else {
        applyArrived();
        applyPending();
        // A new view (or shading) whole at last: shown at once rather than
        // at the next tick, since everything that arrived during its
        // re-sample waits for it.
        if (fullComplete_) {
          fullComplete_ = false;
          onTick();
        }
      }
    }
  }

private:
  Transport& t_;
  PpRankConfig c_;
  int p_;
  Clock::time_point start_;
  StageClock clock_;
  StreamCpu streamCpu_;  // the stream of frames' CPU (cost model)
  bool framePut_ = false;  // tick: a frame's samples or update arrived since the last tick
  RenderSettings render_;
  ControlState state_;
  std::uint32_t epoch_ = 0;
  // The epoch of the last change that re-samples everything (view, shading,
  // transfer function, final passes): messages of older epochs are stale and
  // dropped. A change of the live mode alone starts an epoch too, but the
  // samples still on their way from before it stay valid.
  std::uint32_t samplesEpoch_ = 0;
  TileGrid tiles_;
  std::vector<int> mine_;   // tiles owned, ascending
  std::vector<int> slot_;   // tile -> index in caches_, -1 when not owned
  std::unique_ptr<TileCaches> caches_;
  std::unique_ptr<TileCaches> spare_;  // the other half of a double buffer (prepare)
  bool prepared_ = false;                         // spare_ holds the caches of pending_.front()
  std::vector<std::deque<Message>> queues_;  // per GP, in arrival order
  std::vector<std::int64_t> lastDone_;       // per GP: last frame complete in this epoch (-1: none)
  std::int64_t lastSent_ = -1;               // frame of the last PpDone (tick)
  bool awaitingFull_ = false;                // a full re-sample is being received (tick)
  bool fullComplete_ = false;                // ... and has just been completed
  bool sendAll_ = false;                     // the next image sends every tile (the caches were cleared)
  int fullDone_ = 0;
  std::uint64_t dropped_ = 0;
  std::uint64_t samplesPut_ = 0, rays_ = 0, blocks_ = 0;
  std::uint64_t tileBytesReported_ = 0;  // tile bytes counted in PpDones so far
  std::vector<RaySample> scratch_;  // one batch's samples, decoded
  std::deque<ControlMsg> pending_;  // tick: control changes not applied yet, in order

  CompositeMode live() const { return liveMode(state_); }
  // Whether a change re-samples everything (new caches) rather than only
  // changing the live mode.
  static bool resamples(std::uint32_t ch) {
    return (ch & ControlMsg::kResample) != 0;
  }

  // Caches of this PP's tiles for a control state's view and live mode, made
  // in spare_: the storage of the set used before is reused (RayCache::reset
  // clears only what that view wrote). With the caches in use they make a
  // double buffer: a change's caches are made ready as soon as it arrives,
  // while the current ones still take the frames sent before it
  // (applyPending), and put in place at once when it is applied.
  void prepare(const ControlState& state) {
    const Camera cam = controlCamera(state, c_.render, c_.grid);
    RenderSettings r = render_;
    r.stepScale = state.stepScale;
    const SampleLattice lattice(cam, c_.grid, r.step(c_.grid), r.maxSamples, r.threads, state.pixelStride);
    spare_->reset(lattice.counts(), liveMode(state), state.pixelStride);
    spare_->setValueWindow(state.valueWindow[0], state.valueWindow[1]);
    prepared_ = true;
  }

  // The prepared caches in place; the old ones become the spare set.
  void swapCaches() {
    std::swap(caches_, spare_);
    prepared_ = false;
  }

  void put(const Message& m) {
    const SamplesMsg& sm = m.as<SamplesMsg>();
    const auto payload = m.payload<SamplesMsg>();
    if (sm.tile >= slot_.size() || slot_[sm.tile] < 0)
      throw CommError(fmt::format("rank {} sent samples of tile {}, which PP {} does not own", m.source, sm.tile, p_ + 1));
    clock_.start(kReceive);
    // Decoded into storage kept from batch to batch.
    scratch_.clear();
    if (!decodeSampleRuns(payload, pp::sampleWireFor(c_.cache.format), scratch_, sm.count) ||
        scratch_.size() != sm.count)
      throw CommError(fmt::format("a sample batch from rank {} is malformed: {} bytes do not hold {} samples' runs",
                                  m.source, payload.size(), sm.count));
    clock_.start(kComposite);
    (*caches_)[static_cast<std::size_t>(slot_[sm.tile])].put(scratch_.data(), scratch_.size());
    clock_.stop();
    samplesPut_ += sm.count;
  }

  // lockstep: applies whole updates, in order, once every GP's part is here.
  void applyComplete() {
    for (;;) {
      // Drop what an older epoch left behind (none in lockstep, where the
      // host waits for every image, but harmless).
      for (auto& q : queues_)
        while (!q.empty() && q.front().header().epoch < samplesEpoch_) {
          q.pop_front();
          ++dropped_;
        }
      const Header* key = nullptr;
      for (auto& q : queues_) {
        auto it = std::find_if(q.begin(), q.end(), [](const Message& m) { return m.tag == kTagGpDone; });
        if (it == q.end()) return;
        const Header& h = it->header();
        if (h.epoch > epoch_) return;  // its control has not arrived yet
        if (key && (key->epoch != h.epoch || key->frame != h.frame))
          throw CommError(fmt::format("GPs disagree on the update order: frame {} epoch {} against frame {} epoch {}",
                                      key->frame, key->epoch, h.frame, h.epoch));
        key = &h;
      }
      const Header done = *key;
      for (auto& q : queues_) {
        for (;;) {
          Message m = std::move(q.front());
          q.pop_front();
          if (m.tag == kTagGpDone) break;
          put(m);
        }
      }
      compositeAndSend(done.frame, false);
    }
  }

  // tick: puts everything of the current epoch as it arrives.
  void applyArrived() {
    for (std::size_t g = 0; g < queues_.size(); ++g) {
      auto& q = queues_[g];
      while (!q.empty()) {
        const Header h = q.front().header();
        if (h.epoch < samplesEpoch_) {
          q.pop_front();
          ++dropped_;
          continue;
        }
        if (h.epoch > epoch_) break;
        Message m = std::move(q.front());
        q.pop_front();
        if (m.tag == kTagSamples) {
          if (!awaitingFull_) {
            streamCpu_.begin(t_);
            framePut_ = true;
          }
          put(m);
        } else {
          lastDone_[g] = std::max(lastDone_[g], static_cast<std::int64_t>(h.frame));
          if (!m.as<GpDoneMsg>().full && !awaitingFull_) {
            streamCpu_.begin(t_);  // a frame's update, even one with no samples for this PP
            framePut_ = true;
          }
          if (m.as<GpDoneMsg>().full && awaitingFull_ && ++fullDone_ == c_.layout.gps) {
            awaitingFull_ = false;
            fullComplete_ = true;
          }
        }
      }
    }
  }

  // tick: a control change reaches the PP straight from the host, ahead of
  // the samples of the frames sent before it, which the GPs may still be
  // working on. Those frames go into the old view and out in an image of it
  // first; the change is applied once every GP has finished them (the host
  // shows the old view until the new one is whole), so a view change does
  // not hold back the frames acquired before it.
  void applyPending() {
    while (!pending_.empty()) {
      const ControlMsg& cm = pending_.front();
      if (resamples(cm.changes) && !prepared_) {
        clock_.start(kComposite);
        prepare(cm.state);
        clock_.stop();
      }
      if (cm.afterFrame)
        for (const std::int64_t d : lastDone_)
          if (d < static_cast<std::int64_t>(cm.h.frame)) return;
      const std::int64_t complete = *std::min_element(lastDone_.begin(), lastDone_.end());
      if (!awaitingFull_ && complete > lastSent_) {
        compositeAndSend(static_cast<std::uint64_t>(complete), false);
        lastSent_ = complete;
      }
      const ControlMsg c = cm;
      pending_.pop_front();
      onControl(c);
      applyArrived();  // what the GPs already sent in the new epoch
    }
  }

  void onTick() {
    if (awaitingFull_) return;  // half a view is worse than the old one
    const std::int64_t complete = *std::min_element(lastDone_.begin(), lastDone_.end());
    bool dirty = complete > lastSent_;
    if (!dirty) dirty = caches_->anyPut();
    if (!dirty) return;
    compositeAndSend(static_cast<std::uint64_t>(std::max<std::int64_t>(complete, 0)), false);
    lastSent_ = complete;
    if (framePut_) streamCpu_.end(t_);  // a tick that showed frames' samples
    framePut_ = false;
  }

  void compositeAndSend(std::uint64_t frame, bool all) {
    all = all || sendAll_;
    sendAll_ = false;
    clock_.start(kComposite);
    std::vector<std::pair<int, CompositeStats>> changed;
    for (std::size_t i = 0; i < caches_->size(); ++i) {
      RayCache& cache = (*caches_)[i];
      const CompositeStats cs = cache.composite();
      rays_ += cs.rays;
      blocks_ += cs.blocks;
      cache.resetCounters();
      if (all || !cs.changed.empty()) changed.emplace_back(static_cast<int>(i), cs);
    }
    clock_.start(kSend);
    std::uint32_t sent = 0;
    for (const auto& [i, cs] : changed) {
      const RayCache& cache = (*caches_)[static_cast<std::size_t>(i)];
      const TileRect tr = cache.tile();
      const TileRect r = all ? TileRect{0, 0, tr.width, tr.height} : cs.changed;
      sendTile(cache.image(), tr, r, live());
      ++sent;
    }
    done(frame, sent, false, all);
  }

  void sendTile(const TileImage& im, const TileRect& tile, const TileRect& r, CompositeMode mode, bool request = false) {
    TileMsg tm;
    tm.request = request ? 1 : 0;
    tm.h = {kTagTile, epoch_, 0};
    tm.x0 = tile.x0 + r.x0;
    tm.y0 = tile.y0 + r.y0;
    tm.width = r.width;
    tm.height = r.height;
    tm.mode = static_cast<std::uint8_t>(mode);
    const std::size_t rowBytes = static_cast<std::size_t>(r.width) * 4 * sizeof(float);
    std::vector<std::byte> buf(sizeof tm + rowBytes * static_cast<std::size_t>(r.height));
    std::memcpy(buf.data(), &tm, sizeof tm);
    for (int y = 0; y < r.height; ++y)
      std::memcpy(buf.data() + sizeof tm + rowBytes * static_cast<std::size_t>(y), im.pixel(r.x0, r.y0 + y), rowBytes);
    t_.sendBuffer(0, kTagTile, std::move(buf));
  }

  void done(std::uint64_t frame, std::uint32_t tiles, bool request, bool full) {
    PpDoneMsg d;
    d.h = {kTagPpDone, epoch_, frame};
    d.pp = static_cast<std::uint32_t>(p_);
    d.tiles = tiles;
    d.request = request ? 1 : 0;
    d.full = full ? 1 : 0;
    const std::uint64_t tileBytes = t_.bytesSentByKind()[kTrafficTiles];
    d.tileBytes = tileBytes - tileBytesReported_;
    tileBytesReported_ = tileBytes;
    d.times = clock_.take();
    d.rays = rays_;
    d.blocks = blocks_;
    d.samplesPut = samplesPut_;
    rays_ = blocks_ = samplesPut_ = 0;
    t_.send(0, d);
  }

  void onControl(const ControlMsg& cm) {
    if (cm.h.epoch <= epoch_) throw CommError(fmt::format("a control change for epoch {} after epoch {}", cm.h.epoch, epoch_));
    epoch_ = cm.h.epoch;
    const std::uint32_t ch = cm.changes;
    state_ = cm.state;
    clock_.start(kComposite);
    if (resamples(ch)) {
      // New caches (a new view's, or every sample transparent for a new
      // shading), prepared when the change arrived or here.
      if (!prepared_) prepare(state_);
      swapCaches();
      samplesEpoch_ = epoch_;
      std::fill(lastDone_.begin(), lastDone_.end(), -1);
      lastSent_ = -1;
      sendAll_ = true;
      awaitingFull_ = !c_.parallel.lockstep();  // lockstep waits for whole updates anyway
      fullDone_ = 0;
    } else {
      if (ch & ControlMsg::kMode) {
        caches_->setLiveMode(live());
        caches_->setValueWindow(state_.valueWindow[0], state_.valueWindow[1]);
      }
      // A new live mode only: the same samples, composited again. In lockstep
      // every frame up to the change is in. In tick mode samples of earlier
      // frames may still be on their way (they are kept, see samplesEpoch_),
      // so the image claims only the frames complete; and while a full
      // re-sample is still arriving, the tick sends it once it is whole.
      if (c_.parallel.lockstep()) std::fill(lastDone_.begin(), lastDone_.end(), static_cast<std::int64_t>(cm.h.frame));
      sendAll_ = true;
      if (!awaitingFull_) {
        const std::int64_t complete = *std::min_element(lastDone_.begin(), lastDone_.end());
        compositeAndSend(static_cast<std::uint64_t>(std::max<std::int64_t>(complete, 0)), true);
        lastSent_ = complete;
      }
    }
    clock_.stop();
  }

  void onRequest(const RequestMsg& rm) {
    const auto mode = static_cast<CompositeMode>(rm.mode);
    clock_.start(kComposite);
    std::vector<TileImage> ims;
    for (std::size_t i = 0; i < caches_->size(); ++i) ims.push_back((*caches_)[i].compositeFull(mode));
    clock_.start(kSend);
    for (std::size_t i = 0; i < caches_->size(); ++i) {
      const TileRect tr = (*caches_)[i].tile();
      sendTile(ims[i], tr, TileRect{0, 0, tr.width, tr.height}, mode, true);
    }
    done(rm.h.frame, static_cast<std::uint32_t>(caches_->size()), true, true);
  }
};

}  // namespace

void runPpRank(comm::Transport& t, const PpRankConfig& c) { parallel::runRank<PpRank>(t, c); }

}  // namespace pp5::ranks
