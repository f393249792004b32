#include "host/host_rank.hpp"

#include <algorithm>
#include <optional>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <deque>
#include <memory>
#include <thread>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "parallel/rank_stats.hpp"
#include "parallel/partition.hpp"
#include "parallel/schedule.hpp"
#include "core/error.hpp"
#include "core/image_io.hpp"
#include "core/io_util.hpp"
#include "core/volume_io.hpp"
#include "gp/slice_geometry.hpp"
#include "host/outputs.hpp"
#include "host/slices.hpp"

namespace pp5::host {

namespace {

using namespace pp5::comm;
using namespace pp5::parallel;
using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

double msBetween(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const auto i = static_cast<std::size_t>(std::ceil(q * static_cast<double>(v.size()))) - (q > 0 ? 1 : 0);
  return v[std::min(i, v.size() - 1)];
}

class HostRank {
public:
  HostRank(Transport& t, const HostJob& j)
      : t_(t), j_(j), L_(j.layout), w_(j.pipeline.render.width), h_(j.pipeline.render.height),
        credits_(static_cast<std::size_t>(L_.gps), j.parallel.credits), pp_(static_cast<std::size_t>(L_.pps)),
        lastPixels_(static_cast<std::size_t>(L_.gps), -1) {
    state_ = makeControlState(j_.pipeline.render, j_.pipeline.shading, j_.pipeline.tf);
    fb_.assign(static_cast<std::size_t>(w_) * h_ * 4, 0.0f);
    requestFb_ = fb_;
    nextFb_ = fb_;
    partition_ = makePartition(j_.parallel, L_, j_.grid, j_.pipeline.recon,
                               TileGrid(w_, h_, j_.parallel.tileSize));
    if (j_.verify) {
      // lockstep: every image; tick: the image once every frame is in (what
      // the GPs' batched updates must leave), then those after it.
      serial::PipelineSettings ps = j_.pipeline;
      ps.render.threads = j_.parallel.threads;
      ps.recon.threads = j_.parallel.threads;
      ref_ = std::make_unique<serial::SerialPipeline>(j_.grid, ps, j_.memoryLimitBytes);
    }
  }

  int run();

private:
  Transport& t_;
  const HostJob& j_;
  RankLayout L_;
  int w_, h_;
  std::uint32_t epoch_ = 0;
  ControlState state_;
  std::vector<int> credits_;
  struct PpProgress {
    std::uint32_t epoch = 0;
    std::int64_t frame = -1;
  };
  std::vector<PpProgress> pp_;
  int requestsDone_ = 0;
  std::vector<float> fb_, requestFb_;
  std::int64_t imageFrame_ = -1;  // every frame up to this one is in fb_ (this epoch)
  // Until a new epoch's first whole image is in, fb_ goes on showing (and
  // updating) the epoch before (shownEpoch_, its progress shownPp_): the PPs
  // send the frames acquired before a control change in the old view first.
  // The new epoch's tiles gather in nextFb_ (every PP sends all its tiles
  // first in a new epoch) and replace fb_ at once.
  std::uint32_t shownEpoch_ = 0;
  std::vector<PpProgress> shownPp_;
  std::int64_t shownFrame_ = -1;
  std::vector<float> nextFb_;
  std::uint64_t sent_ = 0;        // frames sent
  std::uint64_t images_ = 0;      // image updates assembled
  std::uint64_t verified_ = 0;
  std::vector<Clock::time_point> arrival_;
  std::vector<double> latencyMs_;
  // GP updates for frames (tick mode batches the frames waiting at a GP).
  std::uint64_t frameCredits_ = 0, framesBatched_ = 0;
  double gpUpdates_ = 0.0;
  std::uint32_t maxBatch_ = 0;
  StageClock clock_;
  StreamCpu streamCpu_;  // the stream of frames' CPU (cost model)

  std::unique_ptr<Partition> partition_;
  std::vector<std::int64_t> lastPixels_;  // per GP: the last frame whose pixels it got
  AcquiredFrame prev_;
  bool hasPrev_ = false;
  std::uint64_t pixelMessages_ = 0, poseOnlyMessages_ = 0, previousMessages_ = 0;

  std::unique_ptr<serial::SerialPipeline> ref_;
  // The live viewer (view.listen), what it has seen of the run, and a
  // recording the page asked for.
  std::unique_ptr<LiveView> live_;
  bool volumeOutstanding_ = false;  // a volume for the viewer's slices is on its way
  double gpBusyMs_ = 0.0, ppBusyMs_ = 0.0;
  struct Sample {  // the counters every 250 ms, for the viewer's rates over the last two seconds
    Clock::time_point t;
    std::uint64_t frames, images;
    double gpBusyMs, ppBusyMs;
  };
  std::deque<Sample> window_;
  Clock::time_point lastFigures_{}, lastKeepAlive_ = Clock::now();
  std::vector<Clock::time_point> lastHeard_;  // per rank: the last message from it (the heartbeat)
  std::unique_ptr<StatsCsv> stats_;
  std::unique_ptr<AnimatedGif> buildup_;
  std::int64_t lastBuildup_ = -1;
  Volume volume_;
  int volumesDone_ = 0;
  std::vector<ReportMsg> reports_;
  // Sample bytes the GPs sent for frames' incremental updates and for full
  // re-samples after control changes (their credits' counts).
  std::uint64_t incrementalSampleBytes_ = 0, fullSampleBytes_ = 0;
  // Tile bytes the PPs sent for incremental image updates (not full images
  // after a control change, not answers to requests).
  std::uint64_t incrementalTileBytes_ = 0;

  // ---- messages -------------------------------------------------------
  void handle(const Message& m) {
    if (m.source > 0 && m.source < static_cast<int>(lastHeard_.size())) lastHeard_[static_cast<std::size_t>(m.source)] = Clock::now();
    switch (m.tag) {
      case kTagAlive: break;
      case kTagCredit: {
        const CreditMsg& c = m.as<CreditMsg>();
        ++credits_[c.gp];
        (c.isControl ? fullSampleBytes_ : incrementalSampleBytes_) += c.bytesSent;
        if (!c.isControl) {
          const std::uint32_t b = std::max<std::uint32_t>(1, c.batch);
          ++frameCredits_;
          gpUpdates_ += 1.0 / b;  // a batch of b frames sends b credits
          if (b > 1) ++framesBatched_;
          maxBatch_ = std::max(maxBatch_, b);
        }
        row(c.h, m.source, Role::Gp, c.times, c.samples, c.bytesSent, c.dirtyVoxels, -1.0, c.isControl != 0);
        break;
      }
      case kTagTile: onTile(m); break;
      case kTagPpDone: {
        const PpDoneMsg& d = m.as<PpDoneMsg>();
        if (d.request == 0 && d.full == 0) incrementalTileBytes_ += d.tileBytes;
        row(d.h, m.source, Role::Pp, d.times, d.samplesPut, 0, 0, -1.0, d.request != 0);
        if (d.request) {
          ++requestsDone_;
        } else if (d.h.epoch == epoch_) {
          PpProgress& p = pp_[d.pp];
          p.epoch = d.h.epoch;
          p.frame = std::max(p.frame, static_cast<std::int64_t>(d.h.frame));
          advanceImage();
        } else if (d.h.epoch == shownEpoch_ && shownEpoch_ != epoch_) {
          PpProgress& p = shownPp_[d.pp];
          p.frame = std::max(p.frame, static_cast<std::int64_t>(d.h.frame));
          advanceShown();
        }
        break;
      }
      case kTagVolume: onVolume(m); break;
      case kTagReport: reports_.push_back(m.as<ReportMsg>()); break;
      default: throw CommError(fmt::format("unexpected message tag {} from rank {}", m.tag, m.source));
    }
  }

  void onTile(const Message& m) {
    const TileMsg& tm = m.as<TileMsg>();
    // An older view's tile is drawn while that view is still shown; the
    // current epoch's tiles wait in nextFb_ until its first image is whole.
    if (!tm.request && tm.h.epoch != epoch_ && !(tm.h.epoch == shownEpoch_ && shownEpoch_ != epoch_)) return;
    const auto payload = m.payload<TileMsg>();
    const std::size_t row = static_cast<std::size_t>(tm.width) * 4;
    if (tm.x0 < 0 || tm.y0 < 0 || tm.width < 0 || tm.height < 0 || tm.x0 + tm.width > w_ || tm.y0 + tm.height > h_ ||
        payload.size() != row * static_cast<std::size_t>(tm.height) * sizeof(float))
      throw CommError(fmt::format("a malformed tile from rank {}", m.source));
    clock_.start(kComposite);
    std::vector<float>& dst = tm.request ? requestFb_ : tm.h.epoch == shownEpoch_ ? fb_ : nextFb_;
    for (int y = 0; y < tm.height; ++y)
      std::memcpy(dst.data() + (static_cast<std::size_t>(tm.y0 + y) * w_ + tm.x0) * 4,
                  payload.data() + static_cast<std::size_t>(y) * row * sizeof(float), row * sizeof(float));
    clock_.stop();
  }

  // Frames up to `f` are in the image shown now: their latency, if not yet set.
  void imageHas(std::int64_t from, std::int64_t f) {
    const auto now = Clock::now();
    for (std::int64_t i = std::max<std::int64_t>(from, 0); i <= f && i < static_cast<std::int64_t>(sent_); ++i) {
      if (static_cast<std::size_t>(i) < latencyMs_.size() && latencyMs_[static_cast<std::size_t>(i)] < 0.0) {
        const double ms = msBetween(arrival_[static_cast<std::size_t>(i)], now);
        latencyMs_[static_cast<std::size_t>(i)] = ms;
        const StageTimes none;
        row(Header{0, shownEpoch_, static_cast<std::uint64_t>(i)}, 0, Role::Host, none, 0, 0, 0, ms, false);
      }
    }
  }

  // An image of the old view while the new one is being made.
  void advanceShown() {
    std::int64_t f = INT64_MAX;
    for (const PpProgress& p : shownPp_) f = std::min(f, p.frame);
    if (f <= shownFrame_) return;
    imageHas(shownFrame_ + 1, f);
    shownFrame_ = f;
    ++images_;
    if (live_) live_->image(fb_, w_, h_, shownEpoch_, f);
  }

  void advanceImage() {
    std::int64_t f = INT64_MAX;
    for (const PpProgress& p : pp_) f = p.epoch == epoch_ ? std::min(f, p.frame) : -1;
    if (f <= imageFrame_) return;
    if (shownEpoch_ != epoch_) {  // the new view's first whole image
      fb_.swap(nextFb_);
      shownEpoch_ = epoch_;
      shownFrame_ = -1;
    }
    imageHas(imageFrame_ + 1, f);
    imageFrame_ = f;
    ++images_;
    if (live_) live_->image(fb_, w_, h_, shownEpoch_, f);
    if (buildup_ && !j_.parallel.lockstep() && f / j_.buildupEvery > lastBuildup_ / j_.buildupEvery) {
      addBuildup();
      lastBuildup_ = f;
    }
  }

  void row(const Header& h, int rank, Role role, const StageTimes& st, std::uint64_t samples, std::uint64_t bytes,
           std::uint64_t dirty, double latency, bool control) {
    if (role != Role::Host) {
      double busy = 0.0;
      for (int s = 0; s < kStageCount; ++s)
        if (s != kWait) busy += st.ms[s];
      (role == Role::Gp ? gpBusyMs_ : ppBusyMs_) += busy;
    }
    if (!stats_) return;
    std::vector<double> v = {static_cast<double>(h.frame), static_cast<double>(h.epoch), static_cast<double>(rank),
                             static_cast<double>(role)};
    for (int s = 0; s < kStageCount; ++s) v.push_back(st.ms[s]);
    v.push_back(static_cast<double>(samples));
    v.push_back(static_cast<double>(bytes));
    v.push_back(static_cast<double>(dirty));
    v.push_back(latency);
    v.push_back(control ? 1.0 : 0.0);
    stats_->row(v);
  }

  // Handles messages until `done()`, waiting for them; CommError names `what`
  // when nothing arrives for parallel.timeout_s.
  template <typename F>
  void waitUntil(F done, const std::string& what) {
    while (!done()) {
      const double w0 = t_.waitSeconds();
      Message m;
      try {
        m = t_.wait(what);
      } catch (const CommError& e) {
        // Name the rank that went quiet, as the heartbeat would.
        const auto [r, age] = quietestRank();
        throw CommError(fmt::format("{}; {} was heard from last, {:.1f} s ago", e.what(), rankName(r), age));
      }
      clock_.add(kWait, 1e3 * (t_.waitSeconds() - w0));
      handle(m);
    }
  }
  // Handles what has arrived; whether there was anything.
  bool pump() {
    bool any = false;
    while (auto m = t_.poll()) {
      handle(*m);
      any = true;
    }
    return any;
  }

  // The heartbeat: every quarter of parallel.timeout_s a keep-alive to every
  // rank, which answers it. Nothing to do (a quiet live source, a pause, the
  // served final volume) is then never mistaken for a dead rank, and a rank
  // that does not answer for parallel.timeout_s is named.
  std::string rankName(int r) const {
    if (r >= 1 && r <= L_.gps) return fmt::format("rank {} (graphics processor {})", r, r - 1);
    return fmt::format("rank {} (pixel processor {})", r, r - 1 - L_.gps);
  }
  // The rank heard from least recently, and how long ago (s).
  std::pair<int, double> quietestRank() const {
    const auto now = Clock::now();
    int worst = 1;
    double age = 0.0;
    for (int r = 1; r < L_.worldSize(); ++r) {
      const double a = std::chrono::duration<double>(now - lastHeard_[static_cast<std::size_t>(r)]).count();
      if (a > age) age = a, worst = r;
    }
    return {worst, age};
  }
  void heartbeat() {
    const auto now = Clock::now();
    const double period = 0.25 * j_.parallel.timeoutS;
    if (std::chrono::duration<double>(now - lastKeepAlive_).count() > period) {
      lastKeepAlive_ = now;
      EmptyMsg ka;
      ka.h = {kTagKeepAlive, epoch_, sent_ ? sent_ - 1 : 0};
      for (int r = 1; r < L_.worldSize(); ++r) t_.send(r, ka);
    }
    const auto [r, age] = quietestRank();
    if (age > j_.parallel.timeoutS)
      throw CommError(fmt::format("{} has not answered the host's heartbeat for {:.1f} s: it died or is stopped "
                                  "(parallel.timeout_s = {} s)",
                                  rankName(r), age, j_.parallel.timeoutS));
  }
  void waitCredits() {
    waitUntil([&] { return std::all_of(credits_.begin(), credits_.end(), [](int c) { return c > 0; }); },
              "a credit from every graphics processor");
  }
  void waitImage(std::int64_t frame) {
    waitUntil([&] { return imageFrame_ >= frame; }, fmt::format("the image of frame {}", frame));
  }

  // ---- frames and controls ---------------------------------------------
  void sendFrame(AcquiredFrame& a) {
    streamCpu_.begin(t_);
    waitCredits();
    clock_.start(kSend);
    const std::uint64_t k = sent_;
    const Frame& f = a.frame;
    std::vector<char> pixels(static_cast<std::size_t>(L_.gps), 1);
    if (partition_->placesFrames()) {
      const bool fill = hasPrev_ && prev_.frame.width == f.width && prev_.frame.height == f.height;
      const gp::WorldBox reach = fill ? gp::fillInReach(prev_.imageToReference, a.imageToReference, f.width, f.height,
                                                        j_.pipeline.recon)
                                      : gp::frameReach(a.imageToReference, f.width, f.height, j_.pipeline.recon);
      std::fill(pixels.begin(), pixels.end(), 0);
      for (const int g : partition_->gpsReached(reach)) pixels[static_cast<std::size_t>(g)] = 1;
    }
    FrameMsg fm;
    fm.h = {kTagFrame, epoch_, k};
    fm.sourceIndex = f.index;
    fm.timeS = a.timeS;
    const auto rm = toRowMajor(a.imageToReference);
    std::copy(rm.begin(), rm.end(), fm.imageToReference);
    fm.width = f.width;
    fm.height = f.height;
    fm.pixelType = static_cast<std::uint8_t>(f.pixelType);
    for (int g = 0; g < L_.gps; ++g) {
      if (pixels[static_cast<std::size_t>(g)]) {
        if (hasPrev_ && lastPixels_[static_cast<std::size_t>(g)] != static_cast<std::int64_t>(k) - 1) {
          // It got the previous frame pose-only, but the fill-in from it reaches this GP.
          PreviousMsg pm;
          pm.h = {kTagPrevious, epoch_, k - 1};
          pm.width = prev_.frame.width;
          pm.height = prev_.frame.height;
          pm.pixelType = static_cast<std::uint8_t>(prev_.frame.pixelType);
          t_.send(L_.gpRank(g), pm, prev_.frame.pixels.data(), prev_.frame.pixels.size());
          ++previousMessages_;
        }
        fm.poseOnly = 0;
        t_.send(L_.gpRank(g), fm, f.pixels.data(), f.pixels.size());
        lastPixels_[static_cast<std::size_t>(g)] = static_cast<std::int64_t>(k);
        ++pixelMessages_;
      } else {
        fm.poseOnly = 1;
        t_.send(L_.gpRank(g), fm);
        ++poseOnlyMessages_;
      }
      --credits_[static_cast<std::size_t>(g)];
    }
    clock_.stop();
    arrival_.push_back(a.arrival);
    latencyMs_.push_back(-1.0);
    if (live_) live_->frame(f, a.imageToReference, k, a.timeS, a.arrival);
    ++sent_;
    if (ref_) ref_->insert(f, a.imageToReference, a.timeS);
    prev_ = std::move(a);
    hasPrev_ = true;
  }

  // lasting = false: a change of the run's own that it undoes (LiveView::epochStarted).
  void sendControl(std::uint32_t changes, const ControlState& next, bool lasting = true) {
    waitCredits();
    if (shownEpoch_ == epoch_) {  // the view shown until the new one is whole
      shownPp_ = pp_;
      shownFrame_ = imageFrame_;
    }
    ++epoch_;
    state_ = next;
    ControlMsg cm;
    cm.h = {kTagControl, epoch_, sent_ ? sent_ - 1 : 0};
    cm.changes = changes;
    cm.afterFrame = sent_ > 0 ? 1 : 0;
    cm.state = next;
    for (int r = 1; r < L_.worldSize(); ++r) t_.send(r, cm);
    for (auto& c : credits_) --c;
    for (PpProgress& p : pp_) p = {epoch_, -1};
    imageFrame_ = -1;
    if (ref_) applyControl(*ref_, changes, next, j_.pipeline.render, j_.grid);
    if (live_) live_->epochStarted(epoch_, next, lasting);
  }

  // The image after the last update, compared with the serial pipeline's.
  void verify(const std::vector<float>& got, const pp::TileImage& want, const std::string& what) {
    if (!ref_) return;
    PP5_CHECK_EQ(want.rgba.size(), got.size());
    if (std::memcmp(got.data(), want.rgba.data(), got.size() * sizeof(float)) != 0) {
      for (std::size_t i = 0; i < got.size(); ++i)
        if (std::memcmp(&got[i], &want.rgba[i], sizeof(float)) != 0) {
          const std::size_t px = i / 4;
          throw InvariantError(fmt::format("{}: the distributed image differs from the serial pipeline's at pixel "
                                           "({}, {}) channel {}: {} against {}",
                                           what, px % static_cast<std::size_t>(w_), px / static_cast<std::size_t>(w_),
                                           i % 4, got[i], want.rgba[i]));
        }
    }
    ++verified_;
  }

  std::vector<std::uint8_t> rgb8(const std::vector<float>& im) const { return pp::toRgb8(pp::TileImage{w_, h_, im}); }
  void addBuildup() {
    if (buildup_) buildup_->add(rgb8(fb_).data());
  }

  void onVolume(const Message& m) {
    const VolumeMsg& vm = m.as<VolumeMsg>();
    const auto type = static_cast<ScalarType>(vm.scalarType);
    if (volume_.bytes.empty()) volume_.allocate(j_.grid, type);
    if (volume_.type != type) throw CommError("graphics processors sent volume pieces of different voxel types");
    const Index3 lo(vm.lo[0], vm.lo[1], vm.lo[2]), hi(vm.hi[0], vm.hi[1], vm.hi[2]);
    const auto bpv = static_cast<std::size_t>(scalarBytes(type));
    const auto payload = m.payload<VolumeMsg>();
    const gp::Box3 box{lo, hi};
    if (!box.empty()) {
      if (glm::any(glm::lessThan(lo, Index3(0))) || glm::any(glm::greaterThan(hi, j_.grid.dims)) ||
          payload.size() != box.voxelCount() * bpv)
        throw CommError(fmt::format("a malformed volume piece from rank {}", m.source));
      const std::size_t rowBytes = static_cast<std::size_t>(hi.x - lo.x) * bpv;
      std::size_t off = 0;
      for (std::int64_t k = lo.z; k < hi.z; ++k)
        for (std::int64_t jj = lo.y; jj < hi.y; ++jj) {
          std::memcpy(volume_.bytes.data() + j_.grid.linear(lo.x, jj, k) * bpv, payload.data() + off, rowBytes);
          off += rowBytes;
        }
    }
    if (vm.last) ++volumesDone_;
    if (volumeOutstanding_ && volumesDone_ == L_.gps) {
      volumeOutstanding_ = false;
      if (live_) live_->volume(volume_);
    }
  }

  // ---- the live viewer -------------------------------------------------
  // What the page asks: a control change (once the last one's image is in,
  // so that a drag does not queue views), a volume for the
  // slices; and the figures it shows. Returns whether acquisition is paused.
  // Serves the viewer: its changes, images and volume; true while it holds
  // acquisition paused. `acted`: set when it sent something (a loop with
  // nothing else to do then does not back off).
  bool serveViewer(bool lockstep, bool& acted) {
    if (!live_) return false;
    if (live_->version() != wantedVersion_) {  // fetched (under the viewer's lock) only when it changed
      wantedVersion_ = live_->version();
      wanted_ = live_->wanted();
    }
    const LiveWanted& w = wanted_;
    const std::uint32_t ch = controlChanges(state_, w.state);
    if (ch && shownEpoch_ == epoch_) {
      acted = true;
      sendControl(ch, w.state);
      if (lockstep && sent_ > 0) {
        waitImage(static_cast<std::int64_t>(sent_) - 1);
        if (ref_) verify(fb_, ref_->image(), "after a change from the viewer");
      }
    }
    if (live_->wantsImage()) {
      acted = true;
      live_->image(fb_, w_, h_, shownEpoch_, shownEpoch_ == epoch_ ? imageFrame_ : shownFrame_);
    }
    if (!volumeOutstanding_ && sent_ > 0 && live_->wantsVolume()) {
      acted = true;
      EmptyMsg rq;
      rq.h = {kTagVolumeRequest, epoch_, sent_ - 1};
      volumesDone_ = 0;
      volumeOutstanding_ = true;
      for (int g = 0; g < L_.gps; ++g) t_.send(L_.gpRank(g), rq);
    }
    if (Clock::now() - lastFigures_ > std::chrono::milliseconds(250)) publishFigures();
    return w.paused;
  }
  // The page's figures (frames in, images out, the ranks' loads, latency).
  void publishFigures() {
    const auto now = Clock::now();
    lastFigures_ = now;
    window_.push_back({now, sent_, images_, gpBusyMs_, ppBusyMs_});
    while (window_.size() > 9) window_.pop_front();
    const Sample& first = window_.front();
    LiveFigures f;
    const double span = std::chrono::duration<double>(now - first.t).count();
    if (span > 0) {
      f.framesPerS = static_cast<double>(sent_ - first.frames) / span;
      f.imagesPerS = static_cast<double>(images_ - first.images) / span;
      f.gpLoad = (gpBusyMs_ - first.gpBusyMs) / (1e3 * span * L_.gps);
      f.ppLoad = (ppBusyMs_ - first.ppBusyMs) / (1e3 * span * L_.pps);
    }
    std::vector<double> lat;
    for (std::size_t i = latencyMs_.size(); i-- > 0 && lat.size() < 90;)
      if (latencyMs_[i] >= 0.0) lat.push_back(latencyMs_[i]);
    f.latencyMedianMs = percentile(lat, 0.5);
    f.latencyP95Ms = percentile(lat, 0.95);
    f.frames = sent_;
    f.dropped = dropped_ ? dropped_() : 0;
    live_->figures(f);
  }
  std::function<std::uint64_t()> dropped_;
  LiveWanted wanted_;
  std::uint64_t wantedVersion_ = 0;

  // After the input: the page steers the final volume until Ctrl-C.
  void serveFinal() {
    live_->servingFinal();
    std::printf("viewer: the final volume stays live at %s until Ctrl-C\n", live_->url().c_str());
    std::fflush(stdout);
    // Waits as the streaming loop does, so a drag's images go out at once;
    // once the backoff is at its longest (the page idle for a while), 5 ms
    // sleeps, since this loop may sit here for hours.
    comm::IdleBackoff idle;
    while (!(j_.interrupt && j_.interrupt->load())) {
      bool acted = pump();
      heartbeat();
      serveViewer(j_.parallel.lockstep(), acted);
      if (acted) idle.reset();
      else if (idle.next() < comm::IdleBackoff::kLongest) idle.pause();
      else std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    waitUntil([&] { return shownEpoch_ == epoch_ && !volumeOutstanding_; }, "the last image for the viewer");
  }

  std::vector<float> request(pp::CompositeMode mode) {
    RequestMsg rq;
    rq.h = {kTagRequest, epoch_, sent_ ? sent_ - 1 : 0};
    rq.mode = static_cast<std::uint8_t>(mode);
    requestsDone_ = 0;
    std::fill(requestFb_.begin(), requestFb_.end(), 0.0f);
    for (int p = 0; p < L_.pps; ++p) t_.send(L_.ppRank(p), rq);
    waitUntil([&] { return requestsDone_ == L_.pps; }, fmt::format("the {} image", pp::compositeModeName(mode)));
    return requestFb_;
  }

  // skipped: frames constant-interval capture left out.
  void writeSummary(double streamS, double totalS, std::uint64_t drops, std::uint64_t skipped,
                    const std::vector<std::string>& wrote);
  std::uint64_t streamImages_ = 0;  // image updates while frames were streaming
};

int HostRank::run() {
  const fs::path dir(j_.outDir);
  const auto start = Clock::now();
  {
    std::vector<std::string> cols = {"frame", "epoch", "rank", "role"};
    for (int s = 0; s < kStageCount; ++s) cols.push_back(std::string(stageName(s)) + "_ms");
    // control: 1 for the update of a control change (a GP's full re-shade and
    // re-sample after a view, shading or final-pass change) or a PP's answer
    // to a request, 0 for a frame's update, so that readers need not guess.
    for (const char* c : {"samples", "bytes_sent", "dirty_voxels", "latency_ms", "control"}) cols.push_back(c);
    stats_ = std::make_unique<StatsCsv>((dir / "stats.csv").string(), cols);
  }
  buildup_ = std::make_unique<AnimatedGif>((dir / "buildup.gif").string(), w_, h_, j_.buildupFps);
  const bool lockstep = j_.parallel.lockstep();

  // Scripted changes by frame, in order.
  std::vector<ScriptedControl> script = j_.script;
  std::stable_sort(script.begin(), script.end(),
                   [](const ScriptedControl& a, const ScriptedControl& b) { return a.afterFrame < b.afterFrame; });
  std::size_t nextScript = 0;

  if (!j_.view.listen.empty()) {
    live_ = std::make_unique<LiveView>(j_.view, j_.grid, j_.pipeline.render, j_.pipeline.recon, j_.pipeline.tf, state_,
                                       j_.outDir);
    std::printf("viewer: open %s\n", live_->url().c_str());
    std::fflush(stdout);
  }
  if (j_.source.prepare) j_.source.prepare();
  // Every rank has allocated its grids and caches before the first frame is
  // acquired, so a live source does not queue behind the start-up.
  t_.barrier();
  Acquisition acq(j_.source, j_.preprocess, j_.queueFrames, j_.drop, j_.paceFps, j_.captureIntervalMm);
  dropped_ = [&acq] { return acq.dropped(); };
  Clock::time_point firstSent{}, lastLog = start;
  std::optional<Clock::time_point> interruptedAt;  // set when interrupted: acquisition stopped
  lastHeard_.assign(static_cast<std::size_t>(L_.worldSize()), Clock::now());
  comm::IdleBackoff idle;
  for (;;) {
    if (pump()) idle.reset();
    heartbeat();
    bool viewerActed = false;
    const bool paused = serveViewer(lockstep, viewerActed);
    if (viewerActed) idle.reset();
    // Before the pause: Ctrl-C ends a paused run too.
    if (!interruptedAt && j_.interrupt && j_.interrupt->load()) {
      spdlog::warn("run: interrupted; finishing the {} frames acquired and those still queued", sent_);
      acq.stop();
      interruptedAt = Clock::now();
    }
    if (paused && !interruptedAt) {
      if (!acq.whilePaused()) break;
      continue;
    }
    AcquiredFrame a;
    if (acq.tryPop(a)) {
      idle.reset();
      if (sent_ == 0) firstSent = Clock::now();
      const std::uint64_t sourceIndex = a.frame.index;
      sendFrame(a);
      streamCpu_.end(t_);
      const std::int64_t k = static_cast<std::int64_t>(sent_) - 1;
      if (lockstep) {
        waitImage(k);
        if (ref_) verify(fb_, ref_->image(), fmt::format("frame {}", k));
        if (k % j_.buildupEvery == 0) addBuildup();
      }
      // By the source's frame index, so that dropped frames do not move the change.
      while (nextScript < script.size() && script[nextScript].afterFrame <= sourceIndex) {
        const ScriptedControl& sc = script[nextScript++];
        const std::uint32_t ch = controlChanges(state_, sc.state);
        if (!ch) continue;
        spdlog::info("run: after frame {}: {}", k, sc.text);
        sendControl(ch, sc.state);
        if (lockstep) {
          waitImage(k);
          if (ref_) verify(fb_, ref_->image(), fmt::format("after frame {} ({})", k, sc.text));
        }
      }
      const auto now = Clock::now();
      if (now - lastLog > std::chrono::seconds(2)) {
        acq.logProgress(sent_, std::chrono::duration<double>(now - firstSent).count());
        lastLog = now;
      }
    } else if (acq.finished()) {
      break;
    } else {
      idle.pause();
    }
  }
  if (sent_ == 0) throw InputError("run: the source gave no frame that can be placed");
  for (; nextScript < script.size(); ++nextScript)
    spdlog::warn("run: the source ended before frame {}; run.script entry \"{}\" was not applied",
                 script[nextScript].afterFrame, script[nextScript].text);
  waitImage(static_cast<std::int64_t>(sent_) - 1);
  const double streamS = std::chrono::duration<double>(Clock::now() - firstSent).count();
  if (live_) {
    publishFigures();  // every frame counted before the final images, which take a while
    live_->inputEnded();
    waitUntil([&] { return !volumeOutstanding_; }, "the volume for the viewer's slices");
  }
  streamImages_ = images_;
  if (ref_ && !lockstep) verify(fb_, ref_->image(), fmt::format("after the last frame ({})", sent_ - 1));

  // The end of the sweep: final passes, then what is shown of the final volume.
  sendControl(ControlMsg::kFinish, state_);
  waitImage(static_cast<std::int64_t>(sent_) - 1);
  if (ref_) verify(fb_, ref_->image(), "after the final passes");
  addBuildup();
  buildup_->close();
  std::vector<std::string> wrote = {"buildup.gif"};
  const ControlState liveState = state_;
  for (const pp::CompositeMode m : j_.pipeline.render.compositing) {
    const std::string mode(enumName(m));
    std::vector<float> im;
    if (compositesGreyValues(m) != compositesGreyValues(liveMode(state_))) {
      // The cache holds the other kind of samples: render this mode live.
      ControlState s = state_;
      s.liveMode = static_cast<std::uint8_t>(m);
      sendControl(controlChanges(state_, s), s, false);
      waitImage(static_cast<std::int64_t>(sent_) - 1);
      im = fb_;
    } else {
      im = request(m);
    }
    if (ref_) verify(im, m == ref_->liveMode() ? ref_->image() : ref_->compositeFull(m), "final " + mode + " image");
    const std::string name = "final_" + mode + ".png";
    writeRgbPng((dir / name).string(), w_, h_, rgb8(im).data());
    wrote.push_back(name);
  }
  if (const std::uint32_t ch = controlChanges(state_, liveState)) {  // back to the live mode
    sendControl(ch, liveState, false);
    waitImage(static_cast<std::int64_t>(sent_) - 1);
  }
  if (j_.mpr || j_.volume || ref_) {
    EmptyMsg rq;
    rq.h = {kTagVolumeRequest, epoch_, sent_ - 1};
    volumesDone_ = 0;
    for (int g = 0; g < L_.gps; ++g) t_.send(L_.gpRank(g), rq);
    waitUntil([&] { return volumesDone_ == L_.gps; }, "the reconstructed volume");
    if (ref_ && volume_.bytes != ref_->reconstructor().output().bytes)
      throw InvariantError("the distributed reconstruction differs from the serial pipeline's");
    if (j_.mpr) {
      for (const auto& p : writeMpr(volume_, j_.mprLook, (dir / "mpr").string()))
        wrote.push_back(fs::path(p).filename().string());
    }
    if (j_.volume) {
      writeVolume((dir / "volume.mha").string(), volume_.as(ScalarType::U8), true);
      wrote.push_back("volume.mha");
    }
  }
  std::vector<double> orbitMs;
  if (j_.orbitFrames > 0) {
    AnimatedGif orbit((dir / "orbit.gif").string(), w_, h_, j_.orbitFps);
    const ControlState base = state_;
    for (int i = 0; i < j_.orbitFrames; ++i) {
      ControlState s = base;
      s.orbitValid = 1;
      s.orbitDeg = 360.0 * i / j_.orbitFrames;
      const auto t0 = Clock::now();
      sendControl(ControlMsg::kView, s, false);
      waitImage(static_cast<std::int64_t>(sent_) - 1);
      orbitMs.push_back(msBetween(t0, Clock::now()));
      if (ref_) verify(fb_, ref_->image(), fmt::format("orbit view {}", i));
      orbit.add(rgb8(fb_).data());
    }
    orbit.close();
    wrote.push_back("orbit.gif");
  }

  if (live_ && live_->serve()) serveFinal();
  if (live_) waitUntil([&] { return !volumeOutstanding_; }, "the volume for the viewer's slices");

  // Quit: every rank reports and leaves.
  EmptyMsg quit;
  quit.h = {kTagQuit, epoch_, sent_ - 1};
  for (int r = 1; r < L_.worldSize(); ++r) t_.send(r, quit);
  waitUntil([&] { return static_cast<int>(reports_.size()) == L_.worldSize() - 1; }, "every rank's report");
  t_.flush();
  stats_.reset();
  wrote.push_back("stats.csv");
  wrote.push_back("summary.json");
  wrote.push_back("settings.toml");
  const double totalS = std::chrono::duration<double>(Clock::now() - start).count();
  if (!orbitMs.empty()) {
    std::sort(orbitMs.begin(), orbitMs.end());
    spdlog::info("run: full re-render after a view change (median of {}): {:.0f} ms", orbitMs.size(),
                 orbitMs[orbitMs.size() / 2]);
  }
  std::printf("run: %llu frames through %d ranks (1 host, %d GP, %d PP; %s partition, %s tiles of %d px, %s) in %.1f s\n",
              static_cast<unsigned long long>(sent_), L_.worldSize(), L_.gps, L_.pps, enumName(j_.parallel.gpPartition).data(),
              enumName(j_.parallel.tileOwner).data(), j_.parallel.tileSize, enumName(j_.parallel.compositeOn).data(),
              totalS);
  acq.printCounts();
  if (ref_) std::printf("  verified: %llu images bitwise equal to the serial pipeline's\n", static_cast<unsigned long long>(verified_));
  writeSummary(streamS, totalS, acq.dropped(), acq.skipped(), wrote);
  // SIGTERM sent to mpirun reaches the host odls_base_sigkill_timeout seconds
  // before mpirun's SIGKILL (docs/cluster.md): say how long the ending took.
  if (interruptedAt)
    spdlog::info("run: every output written {:.2f} s after the interruption", msBetween(*interruptedAt, Clock::now()) / 1e3);
  std::printf("wrote to %s\n", fs::absolute(dir).string().c_str());
  for (const auto& n : wrote) std::printf("  %s\n", n.c_str());
  return 0;
}

void HostRank::writeSummary(double streamS, double totalS, std::uint64_t drops, std::uint64_t skipped,
                            const std::vector<std::string>&) {
  std::vector<double> lat;
  for (double v : latencyMs_)
    if (v >= 0.0) lat.push_back(v);
  ReportMsg host = makeReport(t_, Role::Host, clock_.total(), totalS, 0, 0, streamCpu_);
  std::vector<ReportMsg> all = reports_;
  all.push_back(host);
  std::sort(all.begin(), all.end(), [](const ReportMsg& a, const ReportMsg& b) { return a.rank < b.rank; });
  std::uint64_t bytes = 0;
  std::uint64_t byKind[kTrafficKinds] = {};
  for (const auto& r : all) {
    bytes += r.bytesSent;
    for (int k = 0; k < kTrafficKinds; ++k) byKind[k] += r.bytesByKind[k];
  }
  const double frames = static_cast<double>(std::max<std::uint64_t>(1, sent_));
  std::string json = "{\n";
  json += fmt::format("  \"ranks\": {}, \"gps\": {}, \"pps\": {},\n", L_.worldSize(), L_.gps, L_.pps);
  json += fmt::format("  \"gp_partition\": \"{}\", \"slab_split\": \"{}\", \"tile_owner\": \"{}\", \"tile_size\": {}, "
                      "\"composite_on\": \"{}\",\n",
                      enumName(j_.parallel.gpPartition), enumName(j_.parallel.slabSplit),
                      enumName(j_.parallel.tileOwner), j_.parallel.tileSize, enumName(j_.parallel.compositeOn));
  json += fmt::format("  \"frames\": {}, \"stream_s\": {:.4f}, \"total_s\": {:.4f},\n", sent_, streamS, totalS);
  json += fmt::format("  \"frames_per_s_in\": {:.3f}, \"images_per_s_out\": {:.3f}, \"dropped_frames\": {},\n",
                      sent_ / streamS, streamImages_ / streamS, drops);
  json += fmt::format("  \"capture_interval_mm\": {:g}, \"frames_left_out_by_interval\": {},\n", j_.captureIntervalMm,
                      skipped);
  if (j_.source.statsJson) json += fmt::format("  \"source\": {},\n", j_.source.statsJson());
  json += fmt::format("  \"latency_ms_median\": {:.3f}, \"latency_ms_p95\": {:.3f},\n", percentile(lat, 0.5),
                      percentile(lat, 0.95));
  json += fmt::format("  \"bytes_per_frame\": {:.1f}, \"pixel_messages\": {}, \"pose_only_messages\": {}, "
                      "\"previous_messages\": {},\n",
                      static_cast<double>(bytes) / static_cast<double>(sent_), pixelMessages_, poseOnlyMessages_,
                      previousMessages_);
  // By kind, and the samples split into the frames' incremental updates and
  // the full re-samples after control changes (views, styles, the orbit).
  json += "  \"bytes_per_frame_by_kind\": {";
  for (int k = 0; k < kTrafficKinds; ++k)
    json += fmt::format("{}\"{}\": {:.1f}", k ? ", " : "", kTrafficNames[k], static_cast<double>(byKind[k]) / frames);
  // An incremental frame's traffic: the frame in, its samples, and its
  // image update's tiles (no full images, no final renders).
  const double incremental =
      static_cast<double>(byKind[kTrafficFrames] + incrementalSampleBytes_ + incrementalTileBytes_) / frames;
  json += fmt::format("}},\n  \"incremental_bytes_per_frame\": {{\"total\": {:.1f}, \"frames\": {:.1f}, "
                      "\"samples\": {:.1f}, \"tiles\": {:.1f}}}, \"sample_bytes_full_renders\": {},\n",
                      incremental, static_cast<double>(byKind[kTrafficFrames]) / frames,
                      static_cast<double>(incrementalSampleBytes_) / frames,
                      static_cast<double>(incrementalTileBytes_) / frames, fullSampleBytes_);
  const auto updates = static_cast<std::uint64_t>(std::llround(gpUpdates_));
  json += fmt::format("  \"gp_frame_credits\": {}, \"gp_frame_updates\": {}, \"gp_frames_batched\": {}, "
                      "\"gp_max_batch\": {},\n",
                      frameCredits_, updates, framesBatched_, maxBatch_);
  json += "  \"stages\": {";
  std::printf("  frames/s in %.1f, images/s out %.1f, latency median %.1f ms, p95 %.1f ms, %.0f kB per frame\n",
              sent_ / streamS, streamImages_ / streamS, percentile(lat, 0.5), percentile(lat, 0.95),
              static_cast<double>(bytes) / static_cast<double>(sent_) / 1e3);
  std::printf("  kB per frame: frames %.0f, samples %.0f, tiles %.0f, volume %.0f, control %.0f; an incremental "
              "frame's %.0f (samples %.0f, tiles %.0f)\n",
              static_cast<double>(byKind[kTrafficFrames]) / frames / 1e3,
              static_cast<double>(byKind[kTrafficSamples]) / frames / 1e3,
              static_cast<double>(byKind[kTrafficTiles]) / frames / 1e3,
              static_cast<double>(byKind[kTrafficVolume]) / frames / 1e3,
              static_cast<double>(byKind[kTrafficControl]) / frames / 1e3, incremental / 1e3,
              static_cast<double>(incrementalSampleBytes_) / frames / 1e3,
              static_cast<double>(incrementalTileBytes_) / frames / 1e3);
  std::printf("  GP updates: %llu for %llu frame messages (%llu updated in batches, up to %u frames at once)\n",
              static_cast<unsigned long long>(updates), static_cast<unsigned long long>(frameCredits_),
              static_cast<unsigned long long>(framesBatched_), maxBatch_);
  std::printf("  %-12s %12s %12s %10s\n", "stage", "critical ms", "mean ms", "imbalance");
  for (int s = 0; s < kStageCount; ++s) {
    // The critical path over every rank; the imbalance over the ranks of the
    // role that does the stage (GPs reconstruct, shade and sample; PPs
    // composite; GPs and PPs receive, send and wait), so the host does not
    // skew it.
    const bool gpStage = s == kReconstruct || s == kShade || s == kSample;
    double mx = 0.0, roleMax = 0.0, sum = 0.0;
    int n = 0;
    for (const auto& r : all) {
      mx = std::max(mx, static_cast<double>(r.total.ms[s]));
      const auto role = static_cast<Role>(r.role);
      const bool counts = gpStage ? role == Role::Gp : s == kComposite ? role == Role::Pp : role != Role::Host;
      if (!counts) continue;
      roleMax = std::max(roleMax, static_cast<double>(r.total.ms[s]));
      sum += r.total.ms[s];
      ++n;
    }
    const double mean = n ? sum / n : 0.0;
    const double imbalance = mean > 0 ? roleMax / mean : 0.0;
    json += fmt::format("{}\n    \"{}\": {{\"critical_ms\": {:.3f}, \"mean_ms\": {:.3f}, \"imbalance\": {:.3f}}}",
                        s ? "," : "", stageName(s), mx, mean, imbalance);
    std::printf("  %-12s %12.1f %12.1f %10.2f\n", stageName(s), mx, mean, imbalance);
  }
  json += "\n  },\n  \"per_rank\": [";
  std::printf("  %-5s %-5s %9s %9s %12s %12s\n", "rank", "role", "cpu s", "wall s", "MB sent", "MB received");
  for (std::size_t i = 0; i < all.size(); ++i) {
    const ReportMsg& r = all[i];
    json += fmt::format("{}\n    {{\"rank\": {}, \"role\": \"{}\", \"cpu_s\": {:.4f}, \"wall_s\": {:.4f}, "
                        "\"bytes_sent\": {}, \"bytes_received\": {}, \"messages_sent\": {}, \"messages_received\": {}, "
                        "\"dropped_messages\": {}, \"memory_bytes\": {}, \"stream_cpu_s\": {:.4f}, \"stream_bytes\": {}",
                        i ? "," : "", r.rank, roleName(static_cast<Role>(r.role)), r.cpuS, r.wallS, r.bytesSent,
                        r.bytesReceived, r.messagesSent, r.messagesReceived, r.dropped, r.memoryBytes, r.streamCpuS,
                        r.streamBytes);
    json += ", \"stage_ms\": {";
    for (int s = 0; s < kStageCount; ++s) json += fmt::format("{}\"{}\": {:.3f}", s ? ", " : "", stageName(s), r.total.ms[s]);
    json += "}}";
    std::printf("  %-5u %-5s %9.2f %9.2f %12.1f %12.1f\n", r.rank, roleName(static_cast<Role>(r.role)), r.cpuS, r.wallS,
                static_cast<double>(r.bytesSent) / 1e6, static_cast<double>(r.bytesReceived) / 1e6);
  }
  json += "\n  ]\n}\n";
  io::AtomicFile f((fs::path(j_.outDir) / "summary.json").string());
  f.write(json);
  f.commit();
}

}  // namespace

void applyControl(serial::SerialPipeline& pipe, std::uint32_t changes, const comm::ControlState& next,
                  const RenderSettings& base, const Grid& grid) {
  RenderSettings render = base;
  gp::ShadeSettings shading = pipe.settings().shading;
  TransferFunctionSettings tf;
  applyControlState(next, render, shading, tf);
  if (changes & ControlMsg::kFinish) pipe.finish();
  if (changes & ControlMsg::kMode) pipe.setValueWindow(next.valueWindow[0], next.valueWindow[1]);
  if (changes & (ControlMsg::kShading | ControlMsg::kTransfer)) pipe.setStyle(shading, tf, liveMode(next));
  else if (changes & ControlMsg::kMode) pipe.setLiveMode(liveMode(next));
  if (changes & ControlMsg::kView) pipe.setCamera(controlCamera(next, base, grid), next.stepScale, next.pixelStride);
}

int runHostRank(comm::Transport& t, const HostJob& job) {
  HostRank h(t, job);
  return h.run();
}

}  // namespace pp5::host
