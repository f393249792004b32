// The partitioning benchmark's harness (src/benchmark): layouts, child
// processes, the cost model and the tables, on inputs made here.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <csignal>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <thread>

#include <unistd.h>

#include "benchmark/child_process.hpp"
#include "benchmark/cost_model.hpp"
#include "benchmark/layouts.hpp"
#include "benchmark/report.hpp"

namespace {

namespace fs = std::filesystem;
using namespace pp5::harness;

fs::path tempDir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("pp5_harness_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

std::string readAll(const fs::path& p) {
  std::ifstream in(p);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// ------------------------------------------------------------------ layouts --

TEST(HarnessLayouts, NamesSayWhatTheLayoutIs) {
  EXPECT_EQ(makeLayout(2, 1, "slab").name(), "g2p1_slab_contig_t128");
  Layout l = makeLayout(3, 2, "tile", "interleaved", 64, 30.0);
  EXPECT_EQ(l.name(), "g3p2_tile_inter_t64_paced30");
  l.repeat = 3;
  EXPECT_EQ(l.name(), "g3p2_tile_inter_t64_paced30_r3");
  EXPECT_EQ(l.ranks(), 6);
  EXPECT_TRUE(makeLayout(2, 1, "tile", "contiguous", 128, 30.0).target);
  EXPECT_FALSE(makeLayout(2, 2, "slab").target);
  EXPECT_FALSE(makeLayout(2, 1, "slab", "interleaved").target);
  EXPECT_FALSE(makeLayout(2, 1, "slab", "contiguous", 64).target);
}

TEST(HarnessLayouts, TheSweepCoversBothPartitionsAndRunsThePacedTargetThrice) {
  const std::vector<Layout> all = layouts(false);
  std::set<std::string> names;
  for (const Layout& l : all) EXPECT_TRUE(names.insert(l.name()).second) << "twice: " << l.name();
  EXPECT_EQ(all.front().name(), "g2p1_slab_contig_t128");  // the target first
  for (const char* part : {"slab", "tile"}) {
    std::set<int> repeats;
    for (const Layout& l : all)
      if (l.partition == part && l.paceFps > 0.0) {
        EXPECT_TRUE(l.target) << l.name();
        repeats.insert(l.repeat);
      }
    EXPECT_EQ(repeats, (std::set<int>{1, 2, 3})) << part;
  }
  std::set<int> gps, pps, tiles;
  for (const Layout& l : all) {
    gps.insert(l.gps);
    pps.insert(l.pps);
    tiles.insert(l.tileSize);
  }
  EXPECT_EQ(gps, (std::set<int>{1, 2, 3, 5}));
  EXPECT_EQ(pps, (std::set<int>{1, 2, 3}));
  EXPECT_EQ(tiles, (std::set<int>{64, 128, 256}));

  const std::vector<Layout> quick = layouts(true);
  ASSERT_EQ(quick.size(), 2u);
  EXPECT_EQ(quick[0].name(), "g2p1_slab_contig_t128");
  EXPECT_EQ(quick[1].name(), "g2p1_tile_contig_t128_paced30");
}

// ---------------------------------------------------------- child processes --

TEST(HarnessChild, ExitStatusOutputAndCpu) {
  const fs::path d = tempDir("child");
  const std::string sh = findInPath("sh");
  ASSERT_FALSE(sh.empty());
  ChildResult r = runChild({sh, "-c", "echo hello; echo oops >&2; exit 7"}, (d / "a.log").string(), 10.0);
  EXPECT_EQ(r.status, 7);
  EXPECT_FALSE(r.timedOut);
  EXPECT_FALSE(r.interrupted);
  EXPECT_EQ(readAll(d / "a.log"), "hello\noops\n");
  // The children see Open MPI's root and oversubscribe settings.
  r = runChild({sh, "-c", "test \"$OMPI_ALLOW_RUN_AS_ROOT$OMPI_MCA_rmaps_base_oversubscribe\" = 11"},
               (d / "b.log").string(), 10.0);
  EXPECT_EQ(r.status, 0);
  // CPU time of the reaped child is counted.
  r = runChild({sh, "-c", "i=0; while [ $i -lt 200000 ]; do i=$((i+1)); done"}, (d / "c.log").string(), 60.0);
  EXPECT_EQ(r.status, 0);
  EXPECT_GT(r.cpuS, 0.01);
  EXPECT_GE(r.wallS, 0.0);
}

TEST(HarnessChild, TimeoutAndStopEndTheWholeGroup) {
  const fs::path d = tempDir("timeout");
  const std::string sh = findInPath("sh");
  // A grandchild too: the group is signalled, not just the child.
  ChildResult r = runChild({sh, "-c", "sleep 30 & sleep 30; wait"}, (d / "t.log").string(), 0.3);
  EXPECT_TRUE(r.timedOut);
  EXPECT_FALSE(r.interrupted);
  EXPECT_EQ(r.status, 128 + SIGTERM);
  EXPECT_LT(r.wallS, 10.0);

  std::atomic<bool> stop{false};
  std::thread t([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    stop = true;
  });
  r = runChild({sh, "-c", "sleep 30"}, (d / "s.log").string(), 60.0, &stop);
  t.join();
  EXPECT_TRUE(r.interrupted);
  EXPECT_FALSE(r.timedOut);
  EXPECT_LT(r.wallS, 10.0);

  r = runChild({(d / "no-such-program").string()}, (d / "n.log").string(), 5.0);
  EXPECT_NE(r.status, 0);
}

TEST(HarnessChild, TextHelpers) {
  const fs::path d = tempDir("text");
  std::ofstream(d / "f.txt") << "1\n2\n3\n4\n5\n";
  EXPECT_EQ(tail((d / "f.txt").string(), 2), "4\n5\n");
  EXPECT_EQ(tail((d / "f.txt").string(), 9), "1\n2\n3\n4\n5\n");
  EXPECT_EQ(tail((d / "missing.txt").string(), 2), "");
  EXPECT_EQ(tomlString("a\"b\\c"), "\"a\\\"b\\\\c\"");
  EXPECT_EQ(clockText(75.4), "1:15");
  EXPECT_EQ(clockText(-3), "0:00");
  EXPECT_GE(loadAverage(), 0.0);
  EXPECT_TRUE(findInPath("no-such-program-pp5").empty());
}

// --------------------------------------------------------------- cost model --

// A 1 host + 2 GP + 1 PP run of 10 frames, 2 dropped.
json summary() {
  auto rank = [](int r, const char* role, double cpu, double bytesSent, double bytesReceived, double recon,
                 double shade, double sample, double send, double wait, double composite) {
    return json{{"rank", r},
                {"role", role},
                {"cpu_s", cpu},
                {"bytes_sent", bytesSent},
                {"bytes_received", bytesReceived},
                {"stage_ms",
                 {{"receive", 0.0},
                  {"reconstruct", recon},
                  {"shade", shade},
                  {"sample", sample},
                  {"send", send},
                  {"wait", wait},
                  {"composite", composite}}}};
  };
  json s;
  s["frames"] = 10;
  s["dropped_frames"] = 2;
  s["frames_per_s_in"] = 30.0;
  s["images_per_s_out"] = 29.0;
  s["latency_ms_median"] = 40.0;
  s["latency_ms_p95"] = 80.0;
  s["bytes_per_frame"] = 1e6;
  s["stream_s"] = 1.0;
  s["total_s"] = 1.5;
  s["per_rank"] = json::array({rank(0, "host", 0.5, 1e6, 2e6, 0, 0, 0, 10, 900, 5),
                               rank(1, "GP", 2.0, 3e7, 1e6, 100, 300, 500, 100, 100, 0),
                               rank(2, "GP", 1.0, 2e7, 1e6, 50, 150, 250, 50, 500, 0),
                               rank(3, "PP", 0.8, 2e6, 5e7, 0, 0, 0, 20, 300, 400)});
  s["stages"] = json::object();
  for (const auto& st : kStages) s["stages"][st] = {{"critical_ms", 100.0}, {"mean_ms", 50.0}, {"imbalance", 2.0}};
  return s;
}

void writeStats(const fs::path& dir) {
  // GP 1: frames of 10 + 20 ms busy, one control of 60 ms; GP 2: frames of
  // 5 ms; host and PP rows are not GP updates.
  std::ofstream f(dir / "stats.csv");
  f << "frame,epoch,rank,role,receive_ms,reconstruct_ms,shade_ms,sample_ms,send_ms,wait_ms,composite_ms,samples,"
       "bytes_sent,dirty_voxels,latency_ms,control\n";
  f << "0,0,1,1,0,4,3,2,1,50,0,0,0,0,-1,0\n";
  f << "1,0,1,1,0,8,6,4,2,50,0,0,0,0,-1,0\n";
  f << "1,1,1,1,0,0,30,20,10,50,0,0,0,0,-1,1\n";
  f << "0,0,2,1,0,2,1,1,1,50,0,0,0,0,-1,0\n";
  f << "0,0,3,2,0,0,0,0,0,0,99,0,0,0,-1,0\n";
  f << "0,0,0,0,0,0,0,0,0,0,0,0,0,0,12,0\n";
}

TEST(HarnessCostModel, SplitGpUpdatesReadsTheControlColumn) {
  const fs::path d = tempDir("split");
  writeStats(d);
  const auto sp = splitGpUpdates((d / "stats.csv").string(), {{1, 0.5}, {2, 1.0}});
  ASSERT_TRUE(sp);
  // GP 1: (10 + 20) ms * 0.5 = 15; GP 2: 5 ms * 1.0 = 5. Control: 60 * 0.5 / 1.
  EXPECT_DOUBLE_EQ(sp->first, 15.0);
  EXPECT_DOUBLE_EQ(sp->second, 30.0);
  // Without the column (an older stats.csv) nothing is guessed.
  std::ofstream(d / "old.csv") << "frame,epoch,rank,role,receive_ms,reconstruct_ms,shade_ms,sample_ms,send_ms,wait_ms,"
                                  "composite_ms\n0,0,1,1,0,1,1,1,1,1,0\n";
  EXPECT_FALSE(splitGpUpdates((d / "old.csv").string(), {{1, 1.0}}));
  EXPECT_FALSE(splitGpUpdates((d / "missing.csv").string(), {}));
}

TEST(HarnessCostModel, DeriveFromSummaryAndBaseline) {
  const fs::path d = tempDir("derive");
  writeStats(d);
  Row r;
  r.layout = makeLayout(2, 1, "slab");
  r.dir = d.string();
  r.summary = summary();
  r.baseCpu = {0.1, 0.5, 0.4, 0.3};
  r.baseOk = true;
  Bandwidth bw;
  bw.bytesPerS = 5e9;
  derive(r, 12, bw);
  EXPECT_EQ(r.frames, 10u);
  EXPECT_EQ(r.drops, 2u);  // from summary.json, not a log
  EXPECT_DOUBLE_EQ(r.cpuSum, 4.3);
  EXPECT_DOUBLE_EQ(r.cpuMax, 2.0);
  EXPECT_EQ(r.cpuMaxRank, "GP1");
  EXPECT_DOUBLE_EQ(r.hostCpu, 0.5);
  EXPECT_DOUBLE_EQ(r.gpCpuMax, 2.0);
  EXPECT_DOUBLE_EQ(r.ppCpuMax, 0.8);
  // The busiest rank moves 5e7 bytes (the PP's receipts): 5e6 per frame.
  EXPECT_DOUBLE_EQ(r.maxRankBytesPerFrame, 5e6);
  EXPECT_DOUBLE_EQ(r.modelCpuMs, 200.0);
  EXPECT_DOUBLE_EQ(r.modelShmMs, 200.0 + 1e3 * 5e6 / 5e9);
  EXPECT_DOUBLE_EQ(r.modelEthMs, 200.0 + 1e3 * 5e6 / kEthernetBytesPerS);
  // Less start-up: GP1 1.5 s, GP2 0.6 s, host 0.4 s, PP 0.5 s.
  EXPECT_NEAR(r.steadyCpuMs, 150.0, 1e-9);
  EXPECT_NEAR(r.gpSteadyMaxMs, 150.0, 1e-9);
  EXPECT_NEAR(r.gpSteadySumMs, 210.0, 1e-9);
  EXPECT_NEAR(r.allSteadySumMs, 300.0, 1e-9);
  EXPECT_NEAR(r.gpCpuImbalance, 1.5 / 1.05, 1e-12);
  // GP1's CPU per busy wall ms: 1.5 s over 1000 ms busy; its sample stage's
  // 500 ms are 750 ms CPU, 75 per frame.
  EXPECT_NEAR(r.gpStageCpuMax[2], 75.0, 1e-9);
  // stats.csv: GP1's frame updates, 30 ms busy wall, times 1.5 CPU per wall
  // ms, over 10 frames; its control update 60 ms * 1.5.
  ASSERT_TRUE(r.split);
  EXPECT_NEAR(r.gpFrameCpuMs, 4.5, 1e-9);
  EXPECT_NEAR(r.gpControlCpuMs, 90.0, 1e-9);
  // Imbalance over the role whose work the stage is: composite over the one PP.
  EXPECT_DOUBLE_EQ(r.roleImbalance[6], 1.0);
  EXPECT_NEAR(r.roleImbalance[3], 500.0 / 375.0, 1e-12);
  EXPECT_EQ(perRankCpu(r.summary), (std::vector<double>{0.5, 2.0, 1.0, 0.8}));
  EXPECT_DOUBLE_EQ(num(r.summary, "latency_ms_p95"), 80.0);
  EXPECT_DOUBLE_EQ(num(r.summary, "absent"), 0.0);
}

TEST(HarnessCostModel, SerialStats) {
  const fs::path d = tempDir("serial");
  std::ofstream(d / "stats.csv") << "frame,recon_ms,shade_ms,sample_ms,composite_ms\n0,1,2,3,4\n1,3,4,5,6\n";
  SerialRef r;
  ASSERT_TRUE(readSerialStats((d / "stats.csv").string(), r));
  EXPECT_EQ(r.frames, 2u);
  EXPECT_DOUBLE_EQ(r.reconMs, 2.0);
  EXPECT_DOUBLE_EQ(r.compositeMs, 5.0);
  SerialRef none;
  EXPECT_FALSE(readSerialStats((d / "missing.csv").string(), none));
  // The columns are found by name: the run's own file has an epoch column after the frame's.
  std::ofstream(d / "stats2.csv") << "frame,epoch,recon_ms,shade_ms,sample_ms,composite_ms,total_ms\n"
                                     "0,0,1,2,3,4,10\n1,1,3,4,5,6,18\n";
  SerialRef withEpoch;
  ASSERT_TRUE(readSerialStats((d / "stats2.csv").string(), withEpoch));
  EXPECT_EQ(withEpoch.frames, 2u);
  EXPECT_DOUBLE_EQ(withEpoch.reconMs, 2.0);
  EXPECT_DOUBLE_EQ(withEpoch.shadeMs, 3.0);
  EXPECT_DOUBLE_EQ(withEpoch.compositeMs, 5.0);
  // A file without the stage columns is not a serial run's.
  std::ofstream(d / "other.csv") << "frame,epoch,rank\n0,0,1\n";
  SerialRef other;
  EXPECT_FALSE(readSerialStats((d / "other.csv").string(), other));
}

// ------------------------------------------------------------------- report --

TEST(HarnessReport, RowsMatchTheHeaderAndTheVerdictJudgesTheTarget) {
  const fs::path d = tempDir("report");
  writeStats(d);
  Row ok;
  ok.layout = makeLayout(2, 1, "slab", "contiguous", 128, 30.0);
  ok.dir = d.string();
  ok.summary = summary();
  ok.summary["dropped_frames"] = 0;
  ok.ok = true;
  derive(ok, 10, Bandwidth{5e9, 1e-6, true, "measured"});
  Row failed;
  failed.layout = makeLayout(3, 1, "tile");
  failed.child.status = 3;
  const auto header = csvHeader();
  EXPECT_EQ(csvRow(ok).size(), header.size());
  EXPECT_EQ(csvRow(failed).size(), header.size());
  EXPECT_EQ(csvRow(failed)[10], "failed(3)");
  EXPECT_EQ(verdict(ok).rfind("**met**", 0), 0u) << verdict(ok);
  ok.summary["latency_ms_p95"] = 101.0;
  EXPECT_EQ(verdict(ok).rfind("**not met**", 0), 0u) << verdict(ok);
  ok.summary["latency_ms_p95"] = 80.0;
  ok.drops = 1;
  EXPECT_EQ(verdict(ok).rfind("**not met**", 0), 0u) << verdict(ok);
  ok.drops = 0;

  writeCsv((d / "bench.csv").string(), {ok, failed});
  const std::string csv = readAll(d / "bench.csv");
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 3);
  ReportContext c;
  c.command = "pp5echo bench x.toml";
  c.sequenceFrames = 10;
  c.sequencePath = "/tmp/seq.igs.mha";
  writeMarkdown((d / "summary.md").string(), {ok, failed}, c);
  const std::string md = readAll(d / "summary.md");
  EXPECT_NE(md.find("slab: the target was met in 1 of 1 runs."), std::string::npos) << md;
  EXPECT_NE(md.find("`g3p1_tile_contig_t128`: exit status 3"), std::string::npos) << md;
}

}  // namespace
