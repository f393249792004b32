#pragma once
// Runs the real pp5echo binary for the command-line tests.
#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <sys/wait.h>

namespace pp5::test {

struct CliResult {
  int status;       // exit status, -1 if it did not exit normally
  std::string out;  // stdout and stderr together
};

// The pp5echo the command-line tests run: $PP5_TEST_BINARY when it is set (the
// sanitizer stage runs the release build's command-line tests against its
// sanitized pp5echo), else the one built beside the tests.
inline std::string binary() {
  const char* env = std::getenv("PP5_TEST_BINARY");
  return env && *env ? std::string(env) : std::string(PP5_BINARY);
}

inline CliResult runCli(const std::string& args) {
  const std::string cmd = binary() + " " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  EXPECT_NE(p, nullptr);
  std::string out;
  std::array<char, 4096> buf{};
  while (std::size_t n = fread(buf.data(), 1, buf.size(), p)) out.append(buf.data(), n);
  const int st = pclose(p);
  return {WIFEXITED(st) ? WEXITSTATUS(st) : -1, out};
}

// runCli under the short name the command-line tests use.
inline CliResult run(const std::string& args) { return runCli(args); }

}  // namespace pp5::test
