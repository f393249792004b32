#pragma once
// Child processes for the benchmark: a command run in its own process group
// with its output in a log, stopped after a timeout or on request, with its
// wall and CPU time.
#include <atomic>
#include <string>
#include <vector>

namespace pp5::harness {

struct ChildResult {
  int status = -1;        // exit status; 128 + signal when killed; -1 when it could not start
  bool timedOut = false;
  bool interrupted = false;
  double wallS = 0.0;
  double cpuS = 0.0;      // the whole job: mpirun and every rank it reaped
};

// The executable `name` on PATH, or "" when there is none.
std::string findInPath(const std::string& name);
// Runs argv in its own process group with Open MPI's root and oversubscribe
// settings, stdout and stderr into `logPath`, stdin from /dev/null. After
// `timeoutS`, or once *stop is set, the group gets SIGTERM, then SIGKILL.
ChildResult runChild(const std::vector<std::string>& argv, const std::string& logPath, double timeoutS,
                     const std::atomic<bool>* stop = nullptr);
// The last `lines` lines of a text file.
std::string tail(const std::string& path, int lines);
// The 1-minute load average (/proc/loadavg), 0 when unknown.
double loadAverage();
// A TOML string literal of s.
std::string tomlString(const std::string& s);
// Seconds as m:ss.
std::string clockText(double s);

}  // namespace pp5::harness
