#pragma once
// Shared by the file-parser fuzz targets: the input goes to a scratch file
// (the parsers read files, as pp5echo does), and a parser may only answer bad
// input with InputError. Anything else that escapes (an InvariantError, a
// std::bad_alloc, a std::length_error) is left uncaught, so libFuzzer reports
// it as a crash; the sanitizers catch what does not throw at all.
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <unistd.h>

#include "core/error.hpp"

namespace pp5::fuzz {

// A scratch file for this process, with the given extension (the readers
// choose the format by it).
inline std::string writeInput(const std::uint8_t* data, std::size_t size, const char* ext) {
  static const std::string dir = [] {
    if (access("/dev/shm", W_OK) == 0) return std::string("/dev/shm");
    const char* t = std::getenv("TMPDIR");
    return std::string(t && *t ? t : "/tmp");
  }();
  const std::string path = dir + "/pp5fuzz-" + std::to_string(getpid()) + ext;
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path;
}

// With PP5_FUZZ_SEEDS_DIR set, a target that makes its own seed inputs
// (scripts/fuzz.sh asks before fuzzing) writes them there and exits; called
// from LLVMFuzzerInitialize.
template <class F>
void writeSeedsIfAsked(F&& write) {
  if (const char* dir = std::getenv("PP5_FUZZ_SEEDS_DIR")) {
    write(std::string(dir));
    std::exit(0);
  }
}

template <class F>
void inputErrorsOnly(F&& f) {
  try {
    f();
  } catch (const InputError&) {
    // a clear refusal: what bad input should get
  }
}

}  // namespace pp5::fuzz
