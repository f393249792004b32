#pragma once
// Counter-based randomness: every random number in the simulator is a hash of
// (seed, what it is for, where or when), never the state of a generator. So a
// scatterer's amplitude depends only on its lattice cell and the seed, the
// noise of a pixel only on the frame and the pixel, and results do not
// depend on the order of evaluation or on the number of threads.
#include <cmath>
#include <cstdint>

namespace pp5::sim {

// A 64-bit finaliser with full avalanche (every input bit flips about half of
// the output bits): MurmurHash3's fmix64 constants.
inline std::uint64_t mix64(std::uint64_t k) {
  k ^= k >> 33;
  k *= 0xff51afd7ed558ccdULL;
  k ^= k >> 33;
  k *= 0xc4ceb9fe1a85ec53ULL;
  k ^= k >> 33;
  return k;
}

// A key for one use of randomness (`salt`) under a seed.
inline std::uint64_t mixSeed(std::uint64_t seed, std::uint64_t salt) {
  return mix64(seed * 0x9E3779B97F4A7C15ULL + mix64(salt + 0x632BE59BD9B4E019ULL));
}

inline std::uint64_t latticeHash(std::uint64_t key, std::int64_t i, std::int64_t j, std::int64_t k) {
  const std::uint64_t h = key ^ (static_cast<std::uint64_t>(i) * 0x9E3779B97F4A7C15ULL) ^
                          (static_cast<std::uint64_t>(j) * 0xC2B2AE3D27D4EB4FULL) ^
                          (static_cast<std::uint64_t>(k) * 0x165667B19E3779F9ULL);
  return mix64(h);
}

// Uniform in [0, 1) from the low 16 bits.
inline double unitFromBits(std::uint64_t bits) { return static_cast<double>(bits & 0xFFFFu) * (1.0 / 65536.0); }

// Uniform in (0, 1) from the low 32 bits (never 0, so logs are safe).
inline double openUnitFromBits(std::uint64_t bits) {
  return (static_cast<double>(bits & 0xFFFFFFFFu) + 0.5) * (1.0 / 4294967296.0);
}

// Standard normal from the low 12 bits, through a table of the inverse normal
// CDF at the 4096 bin centres (tails cut near +-3.5 sigma; variance 0.998).
float gaussianFromBits(std::uint64_t bits);

// Standard normal from 64 bits (Box-Muller), for the few places that need
// full tails and precision (A/D noise, tracker noise, path shapes).
inline double gaussianFromHash(std::uint64_t h) {
  const double u1 = openUnitFromBits(h);
  const double u2 = openUnitFromBits(h >> 32);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2);
}

}  // namespace pp5::sim
