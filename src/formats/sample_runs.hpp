#pragma once
// The wire form of ray samples (the payload of a GP's Samples message), after
// IceT's active-pixel encoding: a batch is a list of runs along rays, each a
// header and, unless the run is transparent, its values.
//
//   header: pixel (uint32), k of the first sample (uint16), n (uint16).
//     n < 0x8000: n samples k, k + 1, ... follow, each r, g, b, a;
//     n >= 0x8000: n - 0x8000 transparent samples (all four +0.0), nothing follows.
//   values: 4 x IEEE binary16 (SampleWire::Half) or 4 x float32 (Float), little-endian.
//
// Consecutive samples of a ray (same pixel, k + 1) of the same kind extend a
// run, so a span of water costs 8 bytes, not 24 a sample. Half is exact where
// the PP's cache stores half (render.cache.format = "half", the default): the
// cache converts the float it is given to half with the same rounding, and
// half -> float -> half gives the same bits. Any order of samples encodes
// (runs just get shorter); decoding gives the samples in the encoded order.
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "core/ray_sample.hpp"

namespace pp5 {

enum class SampleWire : std::uint8_t { Half, Float };

struct SampleRunHeader {
  std::uint32_t pixel;
  std::uint16_t k;
  std::uint16_t n;
};
static_assert(sizeof(SampleRunHeader) == 8);

// Bytes of one sample's values.
constexpr std::size_t sampleWireBytes(SampleWire w) { return w == SampleWire::Half ? 8 : 16; }

// Appends the samples' runs to `out`. InvariantError for a k above 65535.
void encodeSampleRuns(std::span<const RaySample> samples, SampleWire wire, std::vector<std::byte>& out);

// Appends the samples of `in` to `out`; false (out unchanged) when `in` is
// not a whole number of well-formed runs, or holds more than maxSamples
// samples (checked before anything is allocated: a transparent run's 8
// bytes can claim 32767 samples).
bool decodeSampleRuns(std::span<const std::byte> in, SampleWire wire, std::vector<RaySample>& out,
                      std::size_t maxSamples = SIZE_MAX);

}  // namespace pp5
