// The command line, end to end: runs the real pp5echo binary.
#include <gtest/gtest.h>

#include "cli_test_util.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <tuple>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "core/error.hpp"
#include "formats/volume_io.hpp"
#include "reconstruction/reconstruction.hpp"

namespace {

using Result = pp5::test::CliResult;
using pp5::test::run;

std::string readFile(const std::filesystem::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void writeFile(const std::filesystem::path& p, const std::string& bytes) {
  std::ofstream(p, std::ios::binary) << bytes;
}

// configs/doll.toml of the source tree.
std::string dollConfig() { return (std::filesystem::path(PP5_SOURCE_DIR) / "configs" / "doll.toml").string(); }

std::filesystem::path tempDir(const std::string& name) {
  auto d = std::filesystem::temp_directory_path() / ("pp5cli-" + name + "-" + std::to_string(::getpid()));
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

TEST(Cli, HelpListsSubcommands) {
  const auto r = run("--help");
  EXPECT_EQ(r.status, 0);
  for (const char* c : {"config", "info", "simulate"}) EXPECT_NE(r.out.find(c), std::string::npos) << c;
}

TEST(Cli, UnknownSubcommandFails) { EXPECT_NE(run("frobnicate").status, 0); }

TEST(Cli, ConfigurationDocsMatchTheSchema) {
  // docs/configuration.md carries the generated option tables verbatim, so a new
  // or changed option without a docs update fails here.
  const auto r = run("config --markdown");
  ASSERT_EQ(r.status, 0) << r.out;
  const std::string docs = readFile(std::filesystem::path(PP5_SOURCE_DIR) / "docs" / "configuration.md");
  EXPECT_NE(docs.find(r.out), std::string::npos)
      << "docs/configuration.md is out of date: run scripts/gen-docs.sh";
}

TEST(Cli, ShippedConfigsAreValid) {
  for (const auto& e : std::filesystem::directory_iterator(std::filesystem::path(PP5_SOURCE_DIR) / "configs")) {
    if (e.path().extension() != ".toml") continue;
    const auto r = run("config " + e.path().string());
    EXPECT_EQ(r.status, 0) << e.path() << ": " << r.out;
  }
}

TEST(Cli, BadConfigGivesOneLineWithFileKeyAndLine) {
  const auto d = tempDir("badcfg");
  const auto cfg = d / "bad.toml";
  std::ofstream(cfg) << "[grid]\nspacing = [1, 1, 1]\nmargin_mm = -3\n";
  auto r = run("config " + cfg.string());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.out.find(cfg.string() + ":3:"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("grid.margin_mm"), std::string::npos) << r.out;
  EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1) << r.out;

  std::ofstream(cfg) << "[grid]\nspaceing = [1, 1, 1]\n";
  r = run("config " + cfg.string());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.out.find("unknown key 'grid.spaceing'"), std::string::npos) << r.out;

  r = run("config " + (d / "missing.toml").string());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.out.find("missing.toml"), std::string::npos) << r.out;
  std::filesystem::remove_all(d);
}

// `config` says yes only to what `run` takes: each of these was printed as
// valid and then refused by `run`. And what a run does not use is said.
TEST(Cli, ConfigRefusesWhatRunWould) {
  const std::string doll = dollConfig();
  const std::pair<const char*, const char*> bad[] = {
      {"--set render.cache.block_size=3", "render.cache.block_size = 3"},
      {"--set parallel.tile_size=100", "parallel.tile_size = 100"},
      {"--set 'run.script=[\"x\"]'", "run.script"},
      {"--set 'board.arm_x_table=[\"1 2 3\"]'", "board.arm_x_table"},
      {"--set 'output.dir=\"\"'", "output.dir is empty"},
  };
  for (const auto& [set, says] : bad) {
    SCOPED_TRACE(set);
    const auto c = run("config " + doll + " " + set);
    EXPECT_EQ(c.status, 1) << c.out;
    EXPECT_NE(c.out.find(says), std::string::npos) << c.out;
    // Four frames and no orbit: the one case run does not refuse (an empty
    // output.dir, which -o fills) runs to its end, and how long it takes is
    // not what is checked.
    const auto r = run("run " + doll + " --serial -o /tmp/pp5cli-never " + set +
                       " --set sim.sweep.max_frames=4 --set run.orbit_frames=0");
    EXPECT_EQ(r.status, std::string(says) == "output.dir is empty" ? 0 : 1) << r.out;  // -o names the folder
  }
  std::filesystem::remove_all("/tmp/pp5cli-never");
  auto r = run("run " + doll + " --serial -o /tmp/pp5cli-never --gps 2");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("--gps: lays out the ranks of a run under mpirun"), std::string::npos) << r.out;
  EXPECT_FALSE(std::filesystem::exists("/tmp/pp5cli-never"));
  // Ignored in this mode: said, and the run goes on.
  const auto d = tempDir("unused");
  r = run("run " + doll + " --serial -o " + (d / "out").string() +
          " --set parallel.tile_size=64 --set board.arm_probe_z_mm=3 --set run.orbit_frames=0 --set run.mpr=false"
          " --set run.volume=false --set sim.sweep.max_frames=4");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("parallel.tile_size lays out the ranks of a run under mpirun"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("board.arm_probe_z_mm belongs to run.source = \"board\""), std::string::npos) << r.out;
  std::filesystem::remove_all(d);
}

// Settings no stage can honour are refused before anything runs, with the
// key and what to do instead: hole filling with the tent method (it was
// ignored without a word), PLUS's skip interval (the same), a drag stride that
// would not start every tile on a strided pixel.
TEST(Cli, SettingsThatCannotWorkAreRefusedUpFront) {
  const std::string doll = dollConfig();
  auto r = run("run " + doll + " --serial -o /tmp/pp5cli-never --set recon.fill_holes=true");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("recon.fill_holes"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("recon.method = trilinear"), std::string::npos) << r.out;
  EXPECT_FALSE(std::filesystem::exists("/tmp/pp5cli-never/volume.mha"));
  r = run("run " + doll + " --serial -o /tmp/pp5cli-never --view 0 --set view.drag_pixel_stride=3");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("view.drag_pixel_stride = 3"), std::string::npos) << r.out;
  // PLUS's SkipInterval, which the pipeline ignored without a word.
  r = run("run " + doll + " --serial -o /tmp/pp5cli-never --set recon.skip_interval=2");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("recon.skip_interval = 2 applies to `reconstruct`"), std::string::npos) << r.out;
  // Negative counts were taken as "not given" (issue 20).
  r = run("run " + doll + " --serial -o /tmp/pp5cli-never --gps -1");
  EXPECT_NE(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("--gps"), std::string::npos) << r.out;
  r = run("reconstruct none.mha --plus-config none.xml --threads -5");
  EXPECT_NE(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("--threads"), std::string::npos) << r.out;
  // A view whose ray cache cannot fit: named, with what to change (it was a bare std::bad_alloc).
  r = run("run " + doll + " --serial -o /tmp/pp5cli-never --set render.width=2048 --set render.height=2048"
          " --set render.step_mm=0.05 --set render.max_samples=65535");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("the ray cache of this view"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("render.step_mm"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("bad_alloc"), std::string::npos) << r.out;
  // With a pixel method, hole filling is taken.
  pp5::gp::ReconSettings s;
  s.method = pp5::gp::Method::Trilinear;
  s.pixel.fillHoles = true;
  EXPECT_NO_THROW(pp5::gp::checkReconSettings(s));
  s.method = pp5::gp::Method::Tent;
  EXPECT_THROW(pp5::gp::checkReconSettings(s), pp5::InputError);
  // Incremental hole filling without hole filling did nothing, without a word.
  s = {};
  s.method = pp5::gp::Method::Nearest;
  s.pixel.fillHolesIncremental = true;
  EXPECT_THROW(pp5::gp::checkReconSettings(s), pp5::InputError);
  s.pixel.fillHoles = true;
  EXPECT_NO_THROW(pp5::gp::checkReconSettings(s));
  // PLUS's arithmetic with the tent method, which computes in float: refused, and named on the command line.
  r = run("run " + doll + " --serial -o /tmp/pp5cli-never --set recon.arithmetic=plus");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("recon.arithmetic = \"plus\" reproduces PLUS's nearest and trilinear"), std::string::npos)
      << r.out;
  s = {};
  s.arithmetic = pp5::gp::Arithmetic::Plus;
  EXPECT_THROW(pp5::gp::checkReconSettings(s), pp5::InputError);
  s.method = pp5::gp::Method::Trilinear;
  EXPECT_NO_THROW(pp5::gp::checkReconSettings(s));
}

// run.script in a serial run (it was ignored there without a word, issue
// 20): a view change after frame 5 leaves the final image a run at that view
// from the start gives, bit for bit (the final passes re-render everything),
// and differs from the run without it.
TEST(Cli, SerialRunAppliesItsScript) {
  const auto d = tempDir("script");
  const std::string doll = dollConfig();
  // Unpaced (doll.toml paces at 30 frames/s): a slow machine would drop frames, and the images differ.
  const std::string common = " --serial --set run.orbit_frames=0 --set run.mpr=false --set run.volume=false"
                             " --set run.pace_fps=0 --set sim.sweep.max_frames=12 --set run.sweep_cache=" +
                             (d / "cache").string();
  auto r = run("run " + doll + common + " -o " + (d / "scripted").string() +
               " --set 'run.script=[\"5 render.azimuth_deg = -60\"]'");
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("after frame 5: 5 render.azimuth_deg = -60"), std::string::npos) << r.out;
  r = run("run " + doll + common + " -o " + (d / "turned").string() + " --set render.azimuth_deg=-60");
  ASSERT_EQ(r.status, 0) << r.out;
  r = run("run " + doll + common + " -o " + (d / "plain").string());
  ASSERT_EQ(r.status, 0) << r.out;
  const std::string scripted = readFile(d / "scripted" / "final_over.png");
  ASSERT_FALSE(scripted.empty());
  EXPECT_EQ(scripted, readFile(d / "turned" / "final_over.png"));
  EXPECT_NE(scripted, readFile(d / "plain" / "final_over.png"));
  // stats.csv gives each frame's view epoch: 0 up to the change after frame 5, 1 from there on.
  {
    std::stringstream rows(readFile(d / "scripted" / "stats.csv"));
    std::string line;
    std::getline(rows, line);
    ASSERT_EQ(line.rfind("frame,epoch,", 0), 0u) << line;
    std::vector<int> epochs;
    while (std::getline(rows, line)) epochs.push_back(std::stoi(line.substr(line.find(',') + 1)));
    ASSERT_EQ(epochs.size(), 12u);
    for (std::size_t i = 0; i < epochs.size(); ++i) EXPECT_EQ(epochs[i], i <= 5 ? 0 : 1) << "frame " << i;
  }
  // An entry after the last frame is named, not dropped without a word.
  r = run("run " + doll + common + " -o " + (d / "late").string() +
          " --set 'run.script=[\"500 render.azimuth_deg = -60\"]'");
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("was not applied"), std::string::npos) << r.out;
  std::filesystem::remove_all(d);
}

// The one-process run takes its frames through the host's acquisition
// thread, as under mpirun: paced at run.pace_fps (it had taken every frame as
// fast as it could, whatever the setting), and a paced source that gets ahead
// of the pipeline drops frames by run.drop, counted and printed. Every frame
// the source gave is either through the pipeline or dropped.
TEST(Cli, SerialRunIsPacedAndDropsAsUnderMpirun) {
  const auto d = tempDir("paced");
  const std::string cfg = std::string(PP5_SOURCE_DIR) + "/tests/configs/mpi_small.toml";
  const std::string common = " --serial --set run.orbit_frames=0 --set run.mpr=false --set run.volume=false"
                             " --set run.script=[] --set run.sweep_cache=" + (d / "cache").string();
  auto counts = [](const std::string& out) {
    const auto t = out.find(" frames through the serial pipeline");
    EXPECT_NE(t, std::string::npos) << out;
    if (t == std::string::npos) return std::pair<int, int>{-1, -1};
    const int through = std::stoi(out.substr(out.rfind('\n', t) + 1 + std::string("run: ").size()));
    const auto dr = out.find("  dropped ");
    return std::pair<int, int>{through, dr == std::string::npos ? 0 : std::stoi(out.substr(dr + 10))};
  };
  // 12 frames at 10 frames/s: the last one leaves the source 1.1 s after the first.
  const auto t0 = std::chrono::steady_clock::now();
  Result r = run("run " + cfg + common + " -o " + (d / "paced").string() +
          " --set sim.sweep.max_frames=12 --set run.pace_fps=10");
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_GE(seconds, 1.1) << r.out;
  auto [through, dropped] = counts(r.out);
  EXPECT_EQ(through + dropped, 12) << r.out;
  // 24 frames at 10,000 frames/s into a queue of one: the pipeline cannot take a frame in 0.1 ms.
  r = run("run " + cfg + common + " -o " + (d / "drops").string() +
          " --set sim.sweep.max_frames=24 --set run.pace_fps=10000 --set run.queue_frames=1 --set run.drop=newest");
  ASSERT_EQ(r.status, 0) << r.out;
  std::tie(through, dropped) = counts(r.out);
  EXPECT_GT(dropped, 0) << r.out;
  EXPECT_GT(through, 0) << r.out;
  EXPECT_EQ(through + dropped, 24) << r.out;
  EXPECT_NE(r.out.find("run.drop = newest"), std::string::npos) << r.out;
  std::filesystem::remove_all(d);
}

// SIGINT stops a serial run's source at its next frame, and the frames taken
// and still queued go through the final passes and every output, as under
// mpirun (the serial run went on to the end of the input, issue 20 item 3).
TEST(Cli, SerialRunStopsOnSigintAndWritesItsOutputs) {
  for (const std::string sig : {"INT", "TERM"}) {
    SCOPED_TRACE(sig);
    const auto d = tempDir("sig" + sig);
    const std::string doll = dollConfig();
    const auto log = d / "run.log";
    // A live simulated sweep of about 360 frames (some 10 s); the signal once
    // a few frames are through (stats.csv: a header, then a row per frame).
    const std::string stats = (d / "out" / "stats.csv").string();
    const Result r = run("run " + doll + " --serial -o " + (d / "out").string() +
                         " --set run.simulate_live=true --set sim.sweep.capture_interval_mm=0.5 --set run.orbit_frames=0"
                         " > " + log.string() + " 2>&1 & p=$!; for i in $(seq 600); do [ \"$(wc -l < " + stats +
                         " 2>/dev/null || echo 0)\" -ge 4 ] && break; sleep 0.1; done; kill -" + sig +
                         " $p; wait $p; echo status=$?");
    const std::string out = readFile(log);
    EXPECT_NE(r.out.find("status=0"), std::string::npos) << r.out << out;
    const auto at = out.find("interrupted; finishing the ");
    ASSERT_NE(at, std::string::npos) << out;
    EXPECT_GT(std::stoi(out.substr(at + 27)), 0) << out;
    for (const char* f : {"final_over.png", "volume.mha", "stats.csv", "buildup.gif"})
      EXPECT_GT(std::filesystem::file_size(d / "out" / f), 0u) << f;
    EXPECT_FALSE(std::filesystem::exists(d / "out" / "RUN_INCOMPLETE.txt")) << "every output was written";
    std::filesystem::remove_all(d);
  }
}

// Runs a bash script, returning what it printed and "status=N" at the end.
std::string shell(const std::string& script) {
  char name[] = "/tmp/pp5cli-script-XXXXXX";
  const int fd = ::mkstemp(name);
  EXPECT_GE(fd, 0);
  ::close(fd);
  writeFile(name, script + "\n");
  FILE* p = popen(("bash " + std::string(name) + " 2>&1; echo status=$?").c_str(), "r");
  EXPECT_NE(p, nullptr);
  std::string out;
  std::array<char, 4096> buf{};
  while (std::size_t n = fread(buf.data(), 1, buf.size(), p)) out.append(buf.data(), n);
  pclose(p);
  std::remove(name);
  return out;
}

// `pp5echo run ARGS` in each run mode: serial, and 4 MPI ranks. `limit`: shell
// commands run first in the host's process only (under mpirun, rank 0's; the
// ranks then talk over TCP, so that a file-size limit meets only the outputs,
// not Open MPI's shared-memory files).
const char* const kRunModes[] = {"serial", "mpi"};
std::string runIn(const std::string& mode, const std::string& args, const std::string& limit = "") {
  const std::string exec = "exec " + pp5::test::binary() + " run " + args;
  if (mode == "serial") return limit + "\n" + exec + " --serial";
  return "export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1\n"
         "mpirun -n 4 --mca btl self,tcp bash -c 'if [ \"$OMPI_COMM_WORLD_RANK\" = 0 ]; then " +
         (limit.empty() ? std::string(":") : limit) + "; fi; " + exec + "'";
}

// A disk that fills up during the outputs (RLIMIT_FSIZE, with SIGXFSZ ignored
// so that a write fails with EFBIG as on a full disk), in a folder an earlier
// run wrote to, in both run modes: the run exits non-zero naming the cause, no
// file under a final name is cut short (PNGs through OpenImageIO had been left
// truncated with exit 1, and the animation's mode was 0600), none of the
// earlier run's images is left beside the new ones (they were), the folder is
// marked unfinished, and a recording in it is never touched.
TEST(Cli, AFullDiskLeavesNoTruncatedOutput) {
  for (const std::string mode : kRunModes) {
    SCOPED_TRACE(mode);
    const auto d = tempDir("fulldisk-" + mode);
    const auto out = d / "out";
    std::filesystem::create_directories(out);
    const std::vector<std::string> earlier = {"buildup.gif", "final_over.png", "final_additive.png", "mpr_axial.png",
                                              "orbit.gif",   "volume.mha",     "stats.csv",          "summary.json"};
    for (const auto& n : earlier) writeFile(out / n, "an earlier run's " + n);
    for (const char* keep : {"recording.mha", "recording-1.mha.journal", "notes.txt"})
      writeFile(out / keep, "kept");
    const std::string cfg = std::string(PP5_SOURCE_DIR) + "/tests/configs/mpi_small.toml";
    const std::string o =
        shell(runIn(mode, cfg + " -o " + out.string() + " --set run.orbit_frames=0", "trap \"\" XFSZ; ulimit -f 30"));
    EXPECT_EQ(o.find("status=0"), std::string::npos) << o;
    EXPECT_NE(o.find("File too large"), std::string::npos) << o;
    if (mode == "mpi") {
      EXPECT_NE(o.find("rank 0 (host)"), std::string::npos) << "the failing rank is named: " << o;
    }
    std::size_t checked = 0;
    for (const auto& e : std::filesystem::directory_iterator(out)) {
      const std::string name = e.path().filename().string();
      EXPECT_NE(name.rfind(".tmp", 0), 0u) << "a temporary left behind: " << name;
      const std::string bytes = readFile(e.path());
      EXPECT_EQ(bytes.find("an earlier run's"), std::string::npos) << name << " is an earlier run's, left beside";
      if (e.path().extension() == ".png") {
        EXPECT_EQ(bytes.substr(bytes.size() >= 8 ? bytes.size() - 8 : 0, 4), "IEND") << name << " is cut short";
        ++checked;
      }
      if (e.path().extension() == ".gif") {
        EXPECT_EQ(bytes.back(), ';') << name << " is cut short";  // the GIF trailer
        ++checked;
      }
      if (e.path().extension() == ".png" || e.path().extension() == ".gif") {
        struct stat st {};
        ASSERT_EQ(::stat(e.path().c_str(), &st), 0);
        EXPECT_EQ(st.st_mode & 0044, 0044u) << name << " is not readable by others, as a new file would be";
      }
    }
    EXPECT_GT(checked, 1u) << "the run failed before any image: " << o;
    EXPECT_TRUE(std::filesystem::exists(out / "RUN_INCOMPLETE.txt")) << "the folder looks complete";
    for (const char* keep : {"recording.mha", "recording-1.mha.journal", "notes.txt"})
      EXPECT_EQ(readFile(out / keep), "kept") << keep;
    // The same folder, a run that finishes: no marker.
    const std::string again = shell(runIn(mode, cfg + " -o " + out.string() + " --set run.orbit_frames=0"));
    EXPECT_NE(again.find("status=0"), std::string::npos) << again;
    EXPECT_FALSE(std::filesystem::exists(out / "RUN_INCOMPLETE.txt"));
    EXPECT_TRUE(std::filesystem::exists(out / "final_over.png"));
    std::filesystem::remove_all(d);
  }
}

// Makes `dir` refuse new files, as a read-only folder or file system does:
// its mode, or for root (whom the mode does not stop) the immutable attribute.
// False where neither works here.
bool makeReadOnly(const std::filesystem::path& dir) {
  std::filesystem::permissions(dir, std::filesystem::perms::owner_read | std::filesystem::perms::owner_exec);
  auto refuses = [&] {
    const auto probe = dir / "probe";
    FILE* f = std::fopen(probe.c_str(), "w");
    if (!f) return true;
    std::fclose(f);
    std::filesystem::remove(probe);
    return false;
  };
  if (refuses()) return true;
  return std::system(("chattr +i " + dir.string() + " 2>/dev/null").c_str()) == 0 && refuses();
}
void undoReadOnly(const std::filesystem::path& dir) {
  [[maybe_unused]] const int r = std::system(("chattr -i " + dir.string() + " 2>/dev/null").c_str());
  std::filesystem::permissions(dir, std::filesystem::perms::owner_all);
}

// A read-only output folder fails at once in both run modes, naming the folder
// and the cause, with a non-zero exit, and before a frame is taken.
TEST(Cli, AReadOnlyFolderFailsBeforeAnyWork) {
  for (const std::string mode : kRunModes) {
    SCOPED_TRACE(mode);
    const auto d = tempDir("readonly-" + mode);
    const auto out = d / "out";
    std::filesystem::create_directories(out);
    if (!makeReadOnly(out)) {
      undoReadOnly(out);
      GTEST_SKIP() << "cannot make a read-only folder here (neither its mode nor chattr +i stops this user)";
    }
    const std::string cfg = std::string(PP5_SOURCE_DIR) + "/tests/configs/mpi_small.toml";
    const std::string o = shell(runIn(mode, cfg + " -o " + out.string()));
    undoReadOnly(out);
    EXPECT_EQ(o.find("status=0"), std::string::npos) << o;
    EXPECT_NE(o.find(out.string()), std::string::npos) << "the folder is named: " << o;
    EXPECT_TRUE(o.find("Permission denied") != std::string::npos || o.find("Operation not permitted") != std::string::npos ||
                o.find("Read-only") != std::string::npos)
        << "the cause is given: " << o;
    EXPECT_EQ(o.find("run: frame"), std::string::npos) << "work began: " << o;
    EXPECT_TRUE(std::filesystem::is_empty(out));
    std::filesystem::remove_all(d);
  }
}

// A recording never starts over the journal of one that was cut off, nor
// into a folder that does not exist: refused before any frame is taken,
// saying how to restore it, and the journal is left as it was.
TEST(Cli, ARecordingNeverStartsOverACutOffOne) {
  const auto d = tempDir("cutoff");
  const auto out = d / "out";
  std::filesystem::create_directories(out);
  writeFile(out / "recording.mha.journal", "PP5ECHO RECORDING JOURNAL 1\nSequence = recording.mha\nEnd\n");
  const std::string cfg = std::string(PP5_SOURCE_DIR) + "/tests/configs/mpi_small.toml";
  Result r = run("record " + cfg + " --serial -o " + out.string());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("recording.mha.journal"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("pp5echo restore"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("run: frame"), std::string::npos) << "frames were taken: " << r.out;
  EXPECT_EQ(readFile(out / "recording.mha.journal"), "PP5ECHO RECORDING JOURNAL 1\nSequence = recording.mha\nEnd\n");
  r = run("run " + cfg + " --serial -o " + out.string() + " --set run.record=\\\"" + (d / "no/such/r.mha").string() +
          "\\\"");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("does not exist"), std::string::npos) << r.out;
  std::filesystem::remove_all(d);
}

// A run refused by its settings (here a bad run.script, found on every rank
// under mpirun) leaves the folder it was given as it found it: an earlier
// run's outputs, and no mark. A run started from the settings.toml of its own
// output folder leaves that file as it is, and with --set overrides, which it
// would write over the user's file, it is refused.
TEST(Cli, ARefusedRunLeavesTheFolderAsItFoundIt) {
  for (const std::string mode : kRunModes) {
    SCOPED_TRACE(mode);
    const auto d = tempDir("refused-" + mode);
    const auto out = d / "out";
    std::filesystem::create_directories(out);
    for (const char* n : {"buildup.gif", "final_over.png", "stats.csv"}) writeFile(out / n, "earlier");
    const std::string cfg = std::string(PP5_SOURCE_DIR) + "/tests/configs/mpi_small.toml";
    const std::string o = shell(runIn(mode, cfg + " -o " + out.string() + " --set 'run.script=[\"soon render.azimuth_deg = 5\"]'"));
    EXPECT_EQ(o.find("status=0"), std::string::npos) << o;
    EXPECT_NE(o.find("run.script"), std::string::npos) << o;
    for (const char* n : {"buildup.gif", "final_over.png", "stats.csv"}) EXPECT_EQ(readFile(out / n), "earlier") << n;
    EXPECT_FALSE(std::filesystem::exists(out / "RUN_INCOMPLETE.txt"));
    std::filesystem::remove_all(d);
  }
  const auto d = tempDir("ownsettings");
  const auto out = d / "out";
  const std::string cfg = std::string(PP5_SOURCE_DIR) + "/tests/configs/mpi_small.toml";
  ASSERT_EQ(run("run " + cfg + " --serial -o " + out.string() + " --set run.orbit_frames=0").status, 0);
  const auto saved = out / "settings.toml";
  writeFile(saved, readFile(saved) + "# the user's note\n");
  const std::string before = readFile(saved);
  Result r = run("run " + saved.string() + " --serial -o " + out.string() + " --set run.volume=false");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("another output folder"), std::string::npos) << r.out;
  EXPECT_EQ(readFile(saved), before);
  r = run("run " + saved.string() + " --serial -o " + out.string());
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(readFile(saved), before) << "the run's own configuration was rewritten";
  EXPECT_TRUE(std::filesystem::exists(out / "final_over.png"));
  std::filesystem::remove_all(d);
}

// A FIFO given as an input is refused at once, naming it (reading one with no
// writer waited forever, issue 20 item 7): a sequence, a TOML config and a
// PLUS device set.
TEST(Cli, SpecialFilesAreRefusedNotWaitedOn) {
  const auto d = tempDir("fifo");
  for (const char* name : {"seq.mha", "cfg.toml", "set.xml"}) {
    const auto p = d / name;
    ASSERT_EQ(::mkfifo(p.c_str(), 0600), 0) << p;
  }
  const std::string doll = dollConfig();
  const std::string seq = (d / "seq.mha").string(), cfg = (d / "cfg.toml").string(), set = (d / "set.xml").string();
  for (const std::string& args :
       {"info " + seq, "config " + cfg, "reconstruct " + seq + " --plus-config " + set + " -o " + (d / "o.mha").string()}) {
    const Result r = run(args + " 2>&1; echo status=$?");
    EXPECT_NE(r.out.find("status=1"), std::string::npos) << args << ": " << r.out;
    EXPECT_NE(r.out.find("FIFO"), std::string::npos) << args << ": " << r.out;
  }
  std::filesystem::remove_all(d);
}

// run.source = "simulator" simulates the sweep once into the cache and
// streams it from there; the second run reuses it, and the volume equals the
// live simulator's (the poses read back agree to 1e-6 mm, so the values to
// float rounding).
TEST(Cli, SimulatedSweepIsCachedAndEqualsTheLiveSimulator) {
  const auto d = tempDir("sweepcache");
  const std::string cfg = std::string(PP5_SOURCE_DIR) + "/tests/configs/mpi_small.toml";
  const std::string common = " --set run.orbit_frames=0 --set run.mpr=false --set 'run.sweep_cache=\"" +
                             (d / "cache").string() + "\"'";
  const auto first = run("run " + cfg + " -o " + (d / "a").string() + common);
  ASSERT_EQ(first.status, 0) << first.out;
  EXPECT_NE(first.out.find("simulating the sweep once"), std::string::npos) << first.out;
  const auto second = run("run " + cfg + " -o " + (d / "b").string() + common);
  ASSERT_EQ(second.status, 0) << second.out;
  EXPECT_EQ(second.out.find("simulating the sweep once"), std::string::npos) << second.out;
  std::size_t sweeps = 0;
  for (const auto& e : std::filesystem::directory_iterator(d / "cache")) sweeps += e.is_directory() ? 1 : 0;
  EXPECT_EQ(sweeps, 1u);
  const auto live = run("run " + cfg + " -o " + (d / "c").string() + common + " --set run.simulate_live=true");
  ASSERT_EQ(live.status, 0) << live.out;
  const pp5::Volume vb = pp5::readVolume((d / "b" / "volume.mha").string());
  const pp5::Volume vc = pp5::readVolume((d / "c" / "volume.mha").string());
  ASSERT_EQ(vb.grid.dims, vc.grid.dims);
  ASSERT_EQ(vb.bytes.size(), vc.bytes.size());
  double worst = 0.0, sum = 0.0;
  for (std::size_t i = 0; i < vb.grid.voxelCount(); ++i) {
    worst = std::max(worst, std::abs(vb.value(i) - vc.value(i)));
    sum += vc.value(i);
  }
  EXPECT_GT(sum, 0.0);
  EXPECT_LT(worst, 0.01);
  // A cache folder that cannot be made: the run simulates live and says so.
  const auto nowhere = run("run " + cfg + " -o " + (d / "e").string() +
                           " --set run.orbit_frames=0 --set run.mpr=false --set 'run.sweep_cache=\"/proc/pp5echo/no\"'");
  EXPECT_EQ(nowhere.status, 0) << nowhere.out;
  EXPECT_NE(nowhere.out.find("simulating every frame live instead"), std::string::npos) << nowhere.out;
  std::filesystem::remove_all(d);
}

TEST(Cli, SetOverridesAreApplied) {
  const auto r = run("config --set grid.margin_mm=7.5 --set output.dir=elsewhere");
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("margin_mm = 7.5"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("dir = 'elsewhere'"), std::string::npos) << r.out;
}

}  // namespace
