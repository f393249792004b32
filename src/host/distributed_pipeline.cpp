#include "host/distributed_pipeline.hpp"

#include <algorithm>
#include <cstring>

#include <fmt/format.h>

#include "core/error.hpp"
#include "reconstruction/slice_geometry.hpp"
#include "pipeline/schedule.hpp"

namespace pp5::host {

using namespace pp5::comm;
using namespace pp5::parallel;

DistributedPipeline::DistributedPipeline(Transport& t, const RunJob& j)
    : t_(t), j_(j), L_(j.layout), w_(j.pipeline.render.width), h_(j.pipeline.render.height),
      credits_(static_cast<std::size_t>(L_.gps), j.parallel.credits), pp_(static_cast<std::size_t>(L_.pps)),
      lastPixels_(static_cast<std::size_t>(L_.gps), -1) {
  fb_.assign(static_cast<std::size_t>(w_) * h_ * 4, 0.0f);
  requestFb_ = fb_;
  nextFb_ = fb_;
  partition_ = makePartition(j_.parallel, L_, j_.grid, j_.pipeline.recon, TileGrid(w_, h_, j_.parallel.tileSize));
  if (j_.verify) {
    // lockstep: every image; tick: the image once every frame is in (what
    // the GPs' batched updates must leave), then those after it.
    serial::PipelineSettings ps = j_.pipeline;
    ps.render.threads = j_.parallel.threads;
    ps.recon.threads = j_.parallel.threads;
    ref_ = std::make_unique<serial::SerialPipeline>(j_.grid, ps, j_.memoryLimitBytes);
  }
}

DistributedPipeline::~DistributedPipeline() = default;

std::vector<std::string> DistributedPipeline::statsColumns() const {
  std::vector<std::string> cols = {"frame", "epoch", "rank", "role"};
  for (int s = 0; s < kStageCount; ++s) cols.push_back(std::string(stageName(s)) + "_ms");
  // control: 1 for the update of a control change (a GP's full re-shade and
  // re-sample after a view, shading or final-pass change) or a PP's answer
  // to a request, 0 for a frame's update, so that readers need not guess.
  for (const char* c : {"samples", "bytes_sent", "dirty_voxels", "latency_ms", "control"}) cols.push_back(c);
  return cols;
}

void DistributedPipeline::start() {
  t_.barrier();
  lastHeard_.assign(static_cast<std::size_t>(L_.worldSize()), Clock::now());
}

// ---- messages -------------------------------------------------------

void DistributedPipeline::handle(const Message& m) {
  if (m.source > 0 && m.source < static_cast<int>(lastHeard_.size()))
    lastHeard_[static_cast<std::size_t>(m.source)] = Clock::now();
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

void DistributedPipeline::onTile(const Message& m) {
  const TileMsg& tm = m.as<TileMsg>();
  // An older view's tile is drawn while that view is still shown; the
  // current epoch's tiles wait in nextFb_ until its first image is whole.
  if (!tm.request && tm.h.epoch != epoch_ && !(tm.h.epoch == shownEpoch_ && shownEpoch_ != epoch_)) return;
  const auto payload = m.payload<TileMsg>();
  const std::size_t rowBytes = static_cast<std::size_t>(tm.width) * 4 * sizeof(float);
  if (tm.x0 < 0 || tm.y0 < 0 || tm.width < 0 || tm.height < 0 || tm.x0 + tm.width > w_ || tm.y0 + tm.height > h_ ||
      payload.size() != rowBytes * static_cast<std::size_t>(tm.height))
    throw CommError(fmt::format("a malformed tile from rank {}", m.source));
  clock_.start(kComposite);
  std::vector<float>& dst = tm.request ? requestFb_ : tm.h.epoch == shownEpoch_ ? fb_ : nextFb_;
  for (int y = 0; y < tm.height; ++y)
    std::memcpy(dst.data() + (static_cast<std::size_t>(tm.y0 + y) * w_ + tm.x0) * 4,
                payload.data() + static_cast<std::size_t>(y) * rowBytes, rowBytes);
  clock_.stop();
}

// Frames up to `f` are in the image shown now: their latency, if not yet set.
void DistributedPipeline::imageHas(std::int64_t from, std::int64_t f) {
  latency_.imageHas(from, f, [&](std::int64_t i, double ms) {
    const StageTimes none;
    row(Header{0, shownEpoch_, static_cast<std::uint64_t>(i)}, 0, Role::Host, none, 0, 0, 0, ms, false);
  });
}

void DistributedPipeline::emitImage() {
  ++tally_.images;
  if (events_.image) events_.image(image());
}

// An image of the old view while the new one is being made.
void DistributedPipeline::advanceShown() {
  std::int64_t f = INT64_MAX;
  for (const PpProgress& p : shownPp_) f = std::min(f, p.frame);
  if (f <= shownFrame_) return;
  imageHas(shownFrame_ + 1, f);
  shownFrame_ = f;
  emitImage();
}

void DistributedPipeline::advanceImage() {
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
  emitImage();
}

void DistributedPipeline::row(const Header& h, int rank, Role role, const StageTimes& st, std::uint64_t samples,
                              std::uint64_t bytes, std::uint64_t dirty, double latency, bool control) {
  if (role != Role::Host) {
    double busy = 0.0;
    for (int s = 0; s < kStageCount; ++s)
      if (s != kWait) busy += st.ms[s];
    (role == Role::Gp ? tally_.gpBusyMs : tally_.ppBusyMs) += busy;
  }
  if (!events_.stats) return;
  std::vector<double> v = {static_cast<double>(h.frame), static_cast<double>(h.epoch), static_cast<double>(rank),
                           static_cast<double>(role)};
  for (int s = 0; s < kStageCount; ++s) v.push_back(st.ms[s]);
  v.push_back(static_cast<double>(samples));
  v.push_back(static_cast<double>(bytes));
  v.push_back(static_cast<double>(dirty));
  v.push_back(latency);
  v.push_back(control ? 1.0 : 0.0);
  events_.stats(v);
}

bool DistributedPipeline::poll() {
  bool any = false;
  while (auto m = t_.poll()) {
    handle(*m);
    any = true;
  }
  heartbeat();
  return any;
}

// The heartbeat: every quarter of parallel.timeout_s a keep-alive to every
// rank, which answers it. Nothing to do (a quiet live source, a pause, the
// served final volume) is then never mistaken for a dead rank, and a rank
// that does not answer for parallel.timeout_s is named.
std::string DistributedPipeline::rankName(int r) const {
  if (r >= 1 && r <= L_.gps) return fmt::format("rank {} (graphics processor {})", r, r - 1);
  return fmt::format("rank {} (pixel processor {})", r, r - 1 - L_.gps);
}

// The rank heard from least recently, and how long ago (s).
std::pair<int, double> DistributedPipeline::quietestRank() const {
  const auto now = Clock::now();
  int worst = 1;
  double age = 0.0;
  for (int r = 1; r < L_.worldSize() && r < static_cast<int>(lastHeard_.size()); ++r) {
    const double a = std::chrono::duration<double>(now - lastHeard_[static_cast<std::size_t>(r)]).count();
    if (a > age) age = a, worst = r;
  }
  return {worst, age};
}

void DistributedPipeline::heartbeat() {
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

void DistributedPipeline::waitCredits() {
  waitUntil([&] { return std::all_of(credits_.begin(), credits_.end(), [](int c) { return c > 0; }); },
            "a credit from every graphics processor");
}

void DistributedPipeline::waitImage(std::int64_t frame) {
  waitUntil([&] { return imageFrame_ >= frame; }, fmt::format("the image of frame {}", frame));
}

// ---- frames and controls ---------------------------------------------

void DistributedPipeline::insert(AcquiredFrame& a) {
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
  latency_.arrived(a.arrival);
  if (events_.frame) events_.frame(a, k);
  ++sent_;
  if (ref_) ref_->insert(f, a.imageToReference, a.timeS);
  prev_ = std::move(a);
  hasPrev_ = true;
  streamCpu_.end(t_);
}

std::uint32_t DistributedPipeline::control(std::uint32_t changes, const ViewState& next, bool) {
  waitCredits();
  if (shownEpoch_ == epoch_) {  // the view shown until the new one is whole
    shownPp_ = pp_;
    shownFrame_ = imageFrame_;
  }
  ++epoch_;
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
  return epoch_;
}

void DistributedPipeline::sync() { waitImage(static_cast<std::int64_t>(sent_) - 1); }

ImageView DistributedPipeline::image() const {
  return {&fb_, w_, h_, shownEpoch_, shownEpoch_ == epoch_ ? imageFrame_ : shownFrame_, shownEpoch_ == epoch_};
}

PipelineCounters DistributedPipeline::counters() const {
  PipelineCounters c = tally_;
  c.frames = sent_;
  c.gps = L_.gps;
  c.pps = L_.pps;
  latency_.recent(c);
  return c;
}

void DistributedPipeline::streamEnded() {
  streamImages_ = tally_.images;
  if (ref_ && !j_.parallel.lockstep())
    verify(fb_, nullptr, fmt::format("after the last frame ({})", sent_ - 1));
}

std::string DistributedPipeline::end(const RunEnd& e) {
  // Quit: every rank reports and leaves.
  EmptyMsg quit;
  quit.h = {kTagQuit, epoch_, sent_ - 1};
  for (int r = 1; r < L_.worldSize(); ++r) t_.send(r, quit);
  waitUntil([&] { return static_cast<int>(reports_.size()) == L_.worldSize() - 1; }, "every rank's report");
  t_.flush();
  return summary(e);
}

}  // namespace pp5::host
