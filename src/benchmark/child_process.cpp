#include "benchmark/child_process.hpp"

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include <fcntl.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fmt/format.h>

extern char** environ;

namespace pp5::harness {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

std::string findInPath(const std::string& name) {
  const char* path = std::getenv("PATH");
  if (!path) return {};
  std::stringstream ss(path);
  std::string d;
  while (std::getline(ss, d, ':')) {
    if (d.empty()) continue;
    const fs::path p = fs::path(d) / name;
    if (::access(p.c_str(), X_OK) == 0) return p.string();
  }
  return {};
}

ChildResult runChild(const std::vector<std::string>& argv, const std::string& logPath, double timeoutS,
                     const std::atomic<bool>* stop) {
  ChildResult r;
  std::vector<std::string> env;
  for (char** e = environ; *e; ++e) {
    const std::string s(*e);
    if (s.rfind("OMPI_ALLOW_RUN_AS_ROOT", 0) == 0 || s.rfind("OMPI_MCA_rmaps_base_oversubscribe=", 0) == 0) continue;
    env.push_back(s);
  }
  for (const char* s : {"OMPI_ALLOW_RUN_AS_ROOT=1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1",
                        "OMPI_MCA_rmaps_base_oversubscribe=1"})
    env.emplace_back(s);
  std::vector<char*> envp, args;
  for (auto& s : env) envp.push_back(s.data());
  envp.push_back(nullptr);
  std::vector<std::string> argCopy = argv;
  for (auto& s : argCopy) args.push_back(s.data());
  args.push_back(nullptr);

  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&fa, 1, logPath.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&fa, 1, 2);
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETPGROUP);
  posix_spawnattr_setpgroup(&attr, 0);
  pid_t pid = 0;
  const auto t0 = Clock::now();
  const int rc = posix_spawn(&pid, args[0], &fa, &attr, args.data(), envp.data());
  posix_spawn_file_actions_destroy(&fa);
  posix_spawnattr_destroy(&attr);
  if (rc != 0) {
    std::ofstream(logPath, std::ios::app) << fmt::format("bench: cannot start {}: {}\n", argv[0], std::strerror(rc));
    return r;
  }
  int sent = 0;  // 0: none, 1: SIGTERM, 2: SIGKILL
  Clock::time_point termAt{};
  for (;;) {
    int st = 0;
    rusage ru{};
    const pid_t w = ::wait4(pid, &st, WNOHANG, &ru);
    if (w == pid) {
      r.wallS = std::chrono::duration<double>(Clock::now() - t0).count();
      r.cpuS = static_cast<double>(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
               1e-6 * static_cast<double>(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec);
      r.status = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + (WIFSIGNALED(st) ? WTERMSIG(st) : 0);
      break;
    }
    if (w < 0 && errno != EINTR) {
      r.status = -1;
      break;
    }
    const double el = std::chrono::duration<double>(Clock::now() - t0).count();
    const bool stopped = stop && stop->load();
    if (sent == 0 && (el > timeoutS || stopped)) {
      r.timedOut = !stopped;
      r.interrupted = stopped;
      ::kill(-pid, SIGTERM);
      termAt = Clock::now();
      sent = 1;
    } else if (sent == 1 && Clock::now() - termAt > std::chrono::seconds(10)) {
      ::kill(-pid, SIGKILL);
      sent = 2;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return r;
}

std::string tail(const std::string& path, int lines) {
  std::ifstream in(path);
  std::vector<std::string> all;
  for (std::string l; std::getline(in, l);) all.push_back(l);
  std::string out;
  for (std::size_t i = all.size() > static_cast<std::size_t>(lines) ? all.size() - lines : 0; i < all.size(); ++i)
    out += all[i] + "\n";
  return out;
}

double loadAverage() {
  std::ifstream in("/proc/loadavg");
  double l = 0.0;
  in >> l;
  return l;
}

std::string tomlString(const std::string& s) {
  std::string o = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') o += '\\';
    o += c;
  }
  return o + "\"";
}

std::string clockText(double s) {
  const long t = std::lround(std::max(0.0, s));
  return fmt::format("{}:{:02d}", t / 60, t % 60);
}

}  // namespace pp5::harness
