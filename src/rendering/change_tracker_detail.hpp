#pragma once
// What rendering/change_tracker.cpp and rendering/change_tracker_sync.cpp share. Not for
// other files; in an unnamed namespace, as it was in the one file.
#include <climits>
#include <cstdint>
#include <cstring>

namespace pp5::gp {

namespace {

constexpr std::int32_t kNone = INT32_MAX;
constexpr std::int64_t kAhead = 8;  // rows fetched ahead

// Voxel i of a volume's bytes as a float.
template <class T>
float loadValue(const std::uint8_t* bytes, std::int64_t i) {
  T v;
  std::memcpy(&v, bytes + i * static_cast<std::int64_t>(sizeof(T)), sizeof(T));
  return static_cast<float>(v);
}

}  // namespace

}  // namespace pp5::gp
