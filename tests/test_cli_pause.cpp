// Ctrl-C (here SIGTERM) while the viewer has paused acquisition, in both run modes: the run
// ends at once, with every output, instead of after the source has run out
// (under mpirun the host's loop went round its pause before looking at the
// interrupt, so a paced file passed by to its end, and an unpaced one waited
// for ever).
#include <gtest/gtest.h>

#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>

#include "cli_test_util.hpp"
#include "ws_client.hpp"

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

std::string slurp(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// Polls until `ok` holds or `seconds` pass.
template <class F>
bool waitFor(double seconds, F ok) {
  const auto end = Clock::now() + std::chrono::duration<double>(seconds);
  while (Clock::now() < end) {
    if (ok()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return ok();
}

TEST(CliPause, CtrlCEndsAPausedRun) {
  for (const std::string mode : {"serial", "mpi"}) {
    SCOPED_TRACE(mode);
    const fs::path d = fs::temp_directory_path() / ("pp5cli-pause-" + mode);
    fs::remove_all(d);
    fs::create_directories(d);
    const fs::path log = d / "run.log", pidFile = d / "pid", statusFile = d / "status";
    // mpi_small's 32 frames at one every 2 s: the source would run for a minute.
    const std::string args = std::string(PP5_SOURCE_DIR) + "/tests/configs/mpi_small.toml -o " + (d / "out").string() +
                             " --view 127.0.0.1:0 --set run.pace_fps=0.5 --set run.orbit_frames=0 --set run.script=[]"
                             " --set run.sweep_cache=" + (d / "cache").string();
    const std::string launch =
        mode == "serial" ? pp5::test::binary() + " run " + args + " --serial"
                         : "bash " + std::string(PP5_SOURCE_DIR) + "/scripts/mpirun.sh 4 " + pp5::test::binary() + " run " + args;
    // In the background; its pid and, once it ends, its exit status in files.
    const std::string cmd = "( " + launch + " > " + log.string() + " 2>&1 & echo $! > " + pidFile.string() +
                            "; wait $!; echo $? > " + statusFile.string() + " ) &";
    ASSERT_EQ(std::system(cmd.c_str()), 0);
    ASSERT_TRUE(waitFor(120, [&] { return slurp(log).find("viewer: open http://127.0.0.1:") != std::string::npos; }))
        << slurp(log);
    const std::string out = slurp(log);
    const auto at = out.find("viewer: open http://127.0.0.1:") + std::string("viewer: open http://127.0.0.1:").size();
    const int port = std::stoi(out.substr(at));
    ASSERT_TRUE(waitFor(10, [&] { return !slurp(pidFile).empty(); }));
    const pid_t pid = static_cast<pid_t>(std::stol(slurp(pidFile)));

    // Pause once the first frame is through (stats.csv: a header, then a row a frame), and wait until
    // the page's figures say so.
    ASSERT_TRUE(waitFor(60, [&] {
      const std::string rows = slurp(d / "out" / "stats.csv");
      return std::count(rows.begin(), rows.end(), '\n') >= 2;
    })) << slurp(log);
    pp5::test::Client page;
    page.connect(port, "");
    page.ws.write(boost::asio::buffer(std::string(R"({"type": "pause"})")));
    bool paused = false;
    const auto until = Clock::now() + std::chrono::seconds(30);
    try {
      while (!paused && Clock::now() < until) paused = page.read().find("\"paused\":true") != std::string::npos;
    } catch (const std::exception& e) {
      ADD_FAILURE() << "the page's socket: " << e.what();
    }
    ASSERT_TRUE(paused) << slurp(log);
    std::this_thread::sleep_for(std::chrono::milliseconds(2500));  // frame 1, due 2 s after frame 0, goes by paused

    // SIGTERM, which scripts/mpirun.sh passes on as Ctrl-C is (a background shell ignores SIGINT).
    const auto sent = Clock::now();
    ASSERT_EQ(::kill(pid, SIGTERM), 0);
    const bool ended = waitFor(45, [&] { return !slurp(statusFile).empty(); });
    const double took = std::chrono::duration<double>(Clock::now() - sent).count();
    if (!ended) {  // mpirun runs in a session of its own: every process of the run, by its folder
      ::kill(pid, SIGKILL);
      (void)std::system(("pkill -KILL -f " + d.string()).c_str());
    }
    ASSERT_TRUE(ended) << "still running 45 s after Ctrl-C\n" << slurp(log);
    EXPECT_EQ(std::stoi(slurp(statusFile)), 0) << slurp(log);
    // Well before the source's end (the paced frames left would take about 55 s more).
    EXPECT_LT(took, 30.0) << slurp(log);
    const std::string end = slurp(log);
    EXPECT_NE(end.find("interrupted; finishing the"), std::string::npos) << end;
    EXPECT_NE(end.find("went by while the viewer paused acquisition"), std::string::npos) << end;
    EXPECT_TRUE(fs::exists(d / "out" / "final_over.png")) << end;
    EXPECT_FALSE(fs::exists(d / "out" / "RUN_INCOMPLETE.txt")) << end;
    fs::remove_all(d);
  }
}

}  // namespace
