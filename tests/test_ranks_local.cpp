// The rank loops without mpirun: the in-process transport (comm/local_transport.hpp)
// keeps MPI's guarantees, and a whole job (host, GPs, PPs as threads of this
// process) gives images bitwise equal to the serial pipeline's (--verify),
// for both partitionings.
#include <gtest/gtest.h>

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <exception>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <unistd.h>

#include "comm/local_transport.hpp"
#include "comm/messages.hpp"
#include "core/error.hpp"
#include "host/distributed_pipeline.hpp"
#include "host/local_pipeline.hpp"
#include "outputs/sinks.hpp"
#include "host/sources.hpp"
#include "pipeline/parallel_settings.hpp"
#include "pipeline/gp_rank.hpp"
#include "pipeline/pp_rank.hpp"
#include "sim/simulate.hpp"

namespace {

namespace fs = std::filesystem;
using namespace pp5;

comm::EmptyMsg header(comm::Tag tag, std::uint64_t frame) {
  comm::EmptyMsg m;
  m.h.tag = tag;
  m.h.frame = frame;
  return m;
}

TEST(LocalTransport, KeepsEachSendersOrderAndCountsBytes) {
  comm::LocalJob job(3, 5.0);
  std::thread a([&] {
    for (std::uint64_t i = 0; i < 50; ++i) job.rank(1).send(0, header(comm::kTagCredit, i), "abc", 3);
  });
  std::thread b([&] {
    for (std::uint64_t i = 0; i < 50; ++i) job.rank(2).send(0, header(comm::kTagPpDone, 100 + i));
  });
  a.join();
  b.join();
  comm::Transport& t = job.rank(0);
  std::uint64_t next1 = 0, next2 = 100;
  for (int i = 0; i < 100; ++i) {
    const comm::Message m = t.wait("a message");
    if (m.source == 1) {
      EXPECT_EQ(m.tag, comm::kTagCredit);
      EXPECT_EQ(m.header().frame, next1++);
      ASSERT_EQ(m.payload<comm::EmptyMsg>().size(), 3u);
    } else {
      ASSERT_EQ(m.source, 2);
      EXPECT_EQ(m.header().frame, next2++);
    }
  }
  EXPECT_EQ(next1, 50u);
  EXPECT_EQ(next2, 150u);
  EXPECT_FALSE(t.poll());
  EXPECT_EQ(t.counters()[1].messagesReceived, 50u);
  EXPECT_EQ(t.counters()[1].bytesReceived, 50 * (sizeof(comm::EmptyMsg) + 3));
  EXPECT_EQ(t.totals().messagesReceived, 100u);
  EXPECT_EQ(job.rank(1).totals().bytesSent, 50 * (sizeof(comm::EmptyMsg) + 3));
  EXPECT_THROW(job.rank(1).send(3, header(comm::kTagQuit, 0)), comm::CommError);
}

// An idle loop yields a while, then sleeps 10 us doubling up to 1 ms, and
// starts short again after work.
TEST(IdleBackoff, YieldsThenDoublesUpToAMillisecond) {
  using us = std::chrono::microseconds;
  comm::IdleBackoff idle;
  std::vector<long> steps;
  for (int i = 0; i < 30; ++i) {
    steps.push_back(static_cast<long>(idle.next().count()));
    idle.pause(us(0));  // capped at zero: a yield, so the test does not sleep
  }
  const std::vector<long> want = {0,  0,  0,  0,  0,   0,   0,   0,   0,    0,    0,    0,    0,    0,    0,
                                  0,  0,  0,  0,  0,   10,  20,  40,  80,   160,  320,  640,  1000, 1000, 1000};
  EXPECT_EQ(steps, want);
  EXPECT_EQ(comm::IdleBackoff::kLongest, us(1000));
  // The cap bounds the step (a PP's next tick comes first); none below zero.
  EXPECT_EQ(idle.step(), us(1000));
  EXPECT_EQ(idle.step(us(50)), us(50));
  EXPECT_EQ(idle.step(us(0)), us(0));
  EXPECT_EQ(idle.step(us(-5)), us(0));
  // However long idle, the step stays at the longest.
  for (int i = 0; i < 1000; ++i) idle.pause(us(0));
  EXPECT_EQ(idle.next(), us(1000));
  idle.reset();
  EXPECT_EQ(idle.next(), us(0));
  EXPECT_EQ(idle.step(us(50)), us(0));
}

TEST(LocalTransport, BroadcastBarrierAndTimeout) {
  comm::LocalJob job(4, 0.2);
  std::vector<comm::GridMsg> got(4);
  std::atomic<int> arrived{0};
  std::vector<std::thread> ts;
  for (int r = 0; r < 4; ++r)
    ts.emplace_back([&, r] {
      comm::GridMsg g;
      if (r == 0) {
        g.dims[0] = 7;
        g.spacing[2] = 0.25;
      }
      job.rank(r).broadcast(g, 0);
      got[static_cast<std::size_t>(r)] = g;
      ++arrived;
      job.rank(r).barrier();
      EXPECT_EQ(arrived.load(), 4);  // nobody passes the barrier before all arrived
    });
  for (auto& t : ts) t.join();
  for (const auto& g : got) {
    EXPECT_EQ(g.dims[0], 7);
    EXPECT_EQ(g.spacing[2], 0.25);
  }
  // Broadcasts are set-up collectives, not peer traffic.
  EXPECT_EQ(job.rank(0).totals().bytesSent, 0u);
  // A barrier that not every rank reaches gives up, and an aborted job's
  // barriers throw at once.
  EXPECT_THROW(job.rank(2).barrier(), comm::CommError);
  job.abort();
  EXPECT_THROW(job.rank(3).barrier(), comm::CommError);
  comm::GridMsg g;
  EXPECT_THROW(job.rank(0).broadcast(g, 0), comm::CommError);
  try {
    job.rank(1).wait("a frame that never comes");
    FAIL() << "no timeout";
  } catch (const comm::CommError& e) {
    EXPECT_NE(std::string(e.what()).find("a frame that never comes"), std::string::npos) << e.what();
  }
}

TEST(LocalTransport, AFailedRankLeavesNoneWaiting) {
  comm::LocalJob job(3, 60.0);
  std::vector<std::string> errors(3);
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<std::thread> ts;
  for (int r = 0; r < 3; ++r)
    ts.emplace_back([&, r] {
      try {
        if (r == 0) throw InputError("rank 0 cannot start");
        job.rank(r).barrier();
      } catch (const std::exception& e) {
        errors[static_cast<std::size_t>(r)] = e.what();
        job.abort();
      }
    });
  for (auto& t : ts) t.join();
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 10.0);
  EXPECT_EQ(errors[0], "rank 0 cannot start");
  for (int r = 1; r < 3; ++r) EXPECT_NE(errors[static_cast<std::size_t>(r)].find("aborted"), std::string::npos) << r;
}

// A small doll sweep for 1 host + 2 GP + 1 PP, lockstep, with a view change
// and a drag. Or in tick mode (`tick`), every frame given at once, so that
// frames wait at the GPs and a GP updates them together (their reported
// changes joined; whether any wait depends on the machine's timing).
host::RunJob smallJob(parallel::GpPartition partition, bool tick) {
  sim::SimSettings ss;
  ss.seed = 1;
  ss.sweep.captureIntervalMm = 6.0;
  ss.sweep.lengthMm = 60.0;
  auto simulator = std::make_shared<sim::SweepSimulator>(ss);
  std::vector<Mat4> poses;
  for (std::size_t i = 0; i < simulator->frameCount(); ++i) poses.push_back(simulator->imageToReference(i));
  const Grid grid =
      sim::fitGrid(poses, simulator->probe().width, simulator->probe().height, Vec3(2.0), 2.0);

  host::RunJob j;
  j.grid = grid;
  j.pipeline.render.width = 128;
  j.pipeline.render.height = 96;
  j.pipeline.render.threads = 1;
  j.pipeline.recon.threads = 1;
  j.parallel.gpPartition = partition;
  j.parallel.tileSize = 32;
  j.parallel.compositeOn = tick ? parallel::CompositeOn::Tick : parallel::CompositeOn::Lockstep;
  j.parallel.batchFrames = 8;
  j.parallel.timeoutS = 30.0;
  j.layout = parallel::RankLayout::choose(4, 2, 1);
  j.source = host::simulatorSource(simulator, grid, 1);
  if (tick) {
    struct Shot {
      Frame frame;
      Mat4 pose;
      double t;
    };
    auto shots = std::make_shared<std::vector<Shot>>();
    simulator->run(1, [&](Frame&& f) {
      const Mat4 pose = simulator->imageToReference(f.index);
      const double t = f.timestamp;
      shots->push_back({std::move(f), pose, t});
    });
    j.source.run = [shots](const host::FrameSink& sink) {
      for (const Shot& s : *shots) sink(s.frame, s.pose, s.t);
    };
  }
  RenderSettings turned = j.pipeline.render;
  turned.azimuthDeg = -60.0;
  j.script.push_back({3, parallel::makeControlState(turned, j.pipeline.shading, j.pipeline.tf), "azimuth -60"});
  // A drag's coarse view (every fourth pixel's ray), then the full one again.
  RenderSettings dragged = turned;
  dragged.azimuthDeg = -45.0;
  dragged.stepScale = 2.0;
  dragged.pixelStride = 4;
  j.script.push_back({5, parallel::makeControlState(dragged, j.pipeline.shading, j.pipeline.tf), "drag"});
  j.script.push_back({7, parallel::makeControlState(turned, j.pipeline.shading, j.pipeline.tf), "drag ends"});
  j.orbitFrames = 2;
  return j;
}

fs::path freshDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("pp5_ranks_local_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// Runs `j` on 1 host + 2 GP + 1 PP, threads of this process, the host
// driving the distributed pipeline into `sinks`; its exit status, and what
// it printed in `out`.
int runDistributed(const host::RunJob& j, const std::vector<host::Sink*>& sinks, std::string& out) {
  comm::LocalJob job(4, j.parallel.timeoutS);
  std::vector<std::exception_ptr> errors(4);
  std::vector<std::thread> ranks;
  for (int r = 1; r < 4; ++r)
    ranks.emplace_back([&, r] {
      try {
        if (j.layout.role(r) == parallel::Role::Gp) {
          ranks::GpRankConfig c{j.grid, j.pipeline.recon, j.pipeline.render, j.pipeline.shading, j.pipeline.tf,
                                j.parallel, j.layout, 0, pp::sampleWireFor(j.pipeline.cache.format)};
          ranks::runGpRank(job.rank(r), c);
        } else {
          ranks::PpRankConfig c{j.grid, j.pipeline.render, j.pipeline.shading, j.pipeline.tf, j.pipeline.cache,
                                j.parallel, j.layout};
          ranks::runPpRank(job.rank(r), c);
        }
      } catch (...) {
        errors[static_cast<std::size_t>(r)] = std::current_exception();
        job.abort();  // no rank waits for this one
      }
    });
  testing::internal::CaptureStdout();
  int status = -1;
  try {
    host::DistributedPipeline pipe(job.rank(0), j);
    status = host::runLoop(pipe, j, sinks);
  } catch (...) {
    errors[0] = std::current_exception();
    job.abort();
  }
  out = testing::internal::GetCapturedStdout();
  for (auto& t : ranks) t.join();
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);
  return status;
}

// Every image after every frame, the view change, the final passes and the
// orbit (lockstep; in tick mode from the last frame on), checked against the
// serial pipeline on the host; every output written.
void runJob(parallel::GpPartition partition, const std::string& name, bool tick = false) {
  host::RunJob j = smallJob(partition, tick);
  const fs::path dir = freshDir(name);
  j.outDir = dir.string();
  j.verify = true;
  const outputs::SinkList sinks = outputs::makeSinks(j);
  std::string out;
  EXPECT_EQ(runDistributed(j, outputs::pointers(sinks), out), 0);
  const auto at = out.find("verified: ");
  ASSERT_NE(at, std::string::npos) << out;
  EXPECT_GE(std::stoi(out.substr(at + 10)), tick ? 3 : 12) << out;
  EXPECT_NE(out.find("images bitwise equal to the serial pipeline's"), std::string::npos) << out;
  for (const char* f : {"final_over.png", "final_mip.png", "volume.mha", "stats.csv", "summary.json"})
    EXPECT_TRUE(fs::exists(dir / f)) << f;
  fs::remove_all(dir);
}

// A sink that writes down what it is handed, in order, each image with a
// hash of its pixels (the figures, which depend on timing, and the
// pipeline's own statistics and summary aside).
class EventLog final : public host::Sink {
public:
  std::vector<std::string> events;
  void start(const host::RunStart& r) override { add(fmt::format("start {}x{}", r.width, r.height)); }
  void frame(const host::AcquiredFrame& a, std::uint64_t k) override {
    add(fmt::format("frame {} (source {})", k, a.frame.index));
  }
  void epochStarted(std::uint32_t epoch, const host::ViewState& s, bool lasting) override {
    add(fmt::format("epoch {} azimuth {} mode {}{}", epoch, s.azimuthDeg, s.liveMode, lasting ? "" : " (own)"));
  }
  void image(const host::ImageView& im) override { add("image " + describe(im)); }
  void inputEnded() override { add("input ended"); }
  void finished(const host::ImageView& im) override { add("finished " + describe(im)); }
  void finalImage(pp::CompositeMode m, const host::ImageView& im) override {
    add(fmt::format("final {} {}", enumName(m), describe(im)));
  }
  bool wantsFinalVolume() const override { return true; }
  void finalVolume(const Volume& v) override {
    add(fmt::format("volume {}x{}x{} hash {}", v.grid.dims.x, v.grid.dims.y, v.grid.dims.z,
                    hash(v.bytes.data(), v.bytes.size())));
  }
  void orbit(int i, int n, const host::ImageView& im) override { add(fmt::format("orbit {}/{} {}", i, n, describe(im))); }
  void ended() override { add("ended"); }

private:
  void add(std::string e) { events.push_back(std::move(e)); }
  static std::uint64_t hash(const void* p, std::size_t n) {
    std::uint64_t h = 1469598103934665603ull;  // FNV-1a
    for (std::size_t i = 0; i < n; ++i) h = (h ^ static_cast<const unsigned char*>(p)[i]) * 1099511628211ull;
    return h;
  }
  static std::string describe(const host::ImageView& im) {
    return fmt::format("epoch {} frame {}{} {}x{} hash {}", im.epoch, im.frame, im.latest ? "" : " (older view)",
                       im.width, im.height, hash(im.rgba->data(), im.rgba->size() * sizeof(float)));
  }
};

// The run loop exists once: whichever pipeline it drives, the sinks are
// handed the same things in the same order, down to every image's pixels.
TEST(RunLoop, BothPipelinesHandTheSinksTheSameEvents) {
  host::RunJob j = smallJob(parallel::GpPartition::Slab, false);
  const fs::path dir = freshDir("events");
  j.outDir = dir.string();
  EventLog distributed, local;
  std::string out;
  ASSERT_EQ(runDistributed(j, {&distributed}, out), 0);
  testing::internal::CaptureStdout();
  host::LocalPipeline pipe(j);
  const int status = host::runLoop(pipe, j, {&local});
  out = testing::internal::GetCapturedStdout();
  ASSERT_EQ(status, 0) << out;
  // Sanity: the log holds each kind of event, so that equal logs say something.
  const auto has = [&](const std::string& what) {
    return std::any_of(local.events.begin(), local.events.end(),
                       [&](const std::string& e) { return e.rfind(what, 0) == 0; });
  };
  for (const char* what : {"start", "frame 9", "epoch 1 azimuth -60", "image", "input ended", "finished",
                           "final over", "final mip", "volume", "orbit 1/2", "ended"})
    EXPECT_TRUE(has(what)) << what;
  EXPECT_EQ(distributed.events, local.events);
  for (std::size_t i = 0; i < std::min(distributed.events.size(), local.events.size()); ++i)
    if (distributed.events[i] != local.events[i]) {
      ADD_FAILURE() << "first difference at event " << i << ": " << distributed.events[i] << " against "
                    << local.events[i];
      break;
    }
  fs::remove_all(dir);
}

// A sink that asks for a snapshot every `every` frames and keeps its own
// copy of the volume, updated only inside the boxes where the loop says the
// snapshot may differ from the one it had: the copy must be the snapshot.
class SnapshotCopy final : public host::Sink {
public:
  explicit SnapshotCopy(int every) : every_(every) {}
  int snapshots = 0, withBoxes = 0;
  void frame(const host::AcquiredFrame&, std::uint64_t) override { ++frames_; }
  bool wantsVolume() const override {
    if (asked_ || frames_ - at_ < every_) return false;
    asked_ = true;
    at_ = frames_;
    return true;
  }
  void volume(const Volume& v, std::uint64_t, const host::VolumeChange& changed) override {
    asked_ = false;
    ++snapshots;
    if (changed.all || copy_.bytes.size() != v.bytes.size()) {
      copy_ = v;
    } else {
      ++withBoxes;
      const std::size_t bpv = static_cast<std::size_t>(scalarBytes(v.type));
      for (const gp::Box3& b : changed.boxes)
        for (std::int64_t z = b.lo.z; z < b.hi.z; ++z)
          for (std::int64_t y = b.lo.y; y < b.hi.y; ++y) {
            const std::size_t at = v.grid.linear(b.lo.x, y, z) * bpv;
            std::memcpy(copy_.bytes.data() + at, v.bytes.data() + at, static_cast<std::size_t>(b.hi.x - b.lo.x) * bpv);
          }
    }
    EXPECT_TRUE(copy_.bytes == v.bytes) << "snapshot " << snapshots << " differs outside the boxes it named";
  }

private:
  int every_;
  int frames_ = 0;
  mutable int at_ = 0;
  mutable bool asked_ = false;
  Volume copy_;
};

// Sinks that ask for snapshots at different rates are each told where a
// snapshot may differ from the one they had last, across the snapshots asked
// for by the other: a sink that updates only there has the whole volume.
TEST(RunLoop, EachSinkLearnsWhereTheVolumeChangedSinceItsLastSnapshot) {
  host::RunJob j = smallJob(parallel::GpPartition::Slab, false);
  const fs::path dir = freshDir("changes");
  j.outDir = dir.string();
  SnapshotCopy often(1), seldom(3);
  std::string out;
  ASSERT_EQ(runDistributed(j, {&often, &seldom}, out), 0);
  EXPECT_GE(seldom.snapshots, 2);
  EXPECT_GT(often.snapshots, seldom.snapshots);
  EXPECT_GE(seldom.withBoxes, 1);  // the boxes were used, not the whole volume each time
  fs::remove_all(dir);
}

TEST(LocalJob, SlabRanksEqualTheSerialPipeline) { runJob(parallel::GpPartition::Slab, "slab"); }
TEST(LocalJob, TileRanksEqualTheSerialPipeline) { runJob(parallel::GpPartition::Tile, "tile"); }
TEST(LocalJob, TickSlabRanksEqualTheSerialPipeline) { runJob(parallel::GpPartition::Slab, "slab_tick", true); }
TEST(LocalJob, TickTileRanksEqualTheSerialPipeline) { runJob(parallel::GpPartition::Tile, "tile_tick", true); }

}  // namespace
