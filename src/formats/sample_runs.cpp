#include "formats/sample_runs.hpp"

#include <algorithm>
#include <cstddef>
#include <cstring>

#include "core/error.hpp"
#include "core/half_float.hpp"

namespace pp5 {

namespace {

constexpr std::uint16_t kTransparent = 0x8000;
constexpr std::uint16_t kMaxRun = 0x7fff;

// A sample's four values, r g b a, one after the other (the strided
// conversions read them as a group of four floats).
static_assert(offsetof(RaySample, g) == offsetof(RaySample, r) + 4 && offsetof(RaySample, b) == offsetof(RaySample, r) + 8 &&
              offsetof(RaySample, a) == offsetof(RaySample, r) + 12);
// Where sample i's values begin, as bytes of the array (the strided
// conversions step from there by sizeof(RaySample)).
const std::byte* valuesOf(const RaySample* s) { return reinterpret_cast<const std::byte*>(s) + offsetof(RaySample, r); }
std::byte* valuesOf(RaySample* s) { return reinterpret_cast<std::byte*>(s) + offsetof(RaySample, r); }

bool transparent(const RaySample& s) {
  const float v[4] = {s.r, s.g, s.b, s.a};
  std::uint32_t bits[4];
  std::memcpy(bits, v, sizeof bits);
  return (bits[0] | bits[1] | bits[2] | bits[3]) == 0;
}

// The run that starts at samples[i]: its length and whether it is transparent.
std::size_t runAt(std::span<const RaySample> samples, std::size_t i, bool& clear) {
  const RaySample& first = samples[i];
  PP5_CHECK_LE(first.k, 0xffffu);
  clear = transparent(first);
  std::size_t n = 1;
  while (i + n < samples.size() && n < kMaxRun) {
    const RaySample& s = samples[i + n];
    if (s.pixel != first.pixel || s.k != first.k + n || transparent(s) != clear) break;
    ++n;
  }
  PP5_CHECK_LE(first.k + n - 1, 0xffffu);
  return n;
}

}  // namespace

void encodeSampleRuns(std::span<const RaySample> samples, SampleWire wire, std::vector<std::byte>& out) {
  const std::size_t valueBytes = sampleWireBytes(wire);
  const std::size_t worst = sizeof(SampleRunHeader) + valueBytes;  // bytes of one sample at most
  // Room is made for the worst case (every sample a run of its own) of up to
  // 2048 of the samples left at a time and cut to what was written at the
  // end: the samples are read once, and the room is zeroed while in cache.
  std::size_t at = out.size();
  try {
    for (std::size_t i = 0; i < samples.size();) {
      bool clear = false;
      const std::size_t n = runAt(samples, i, clear);
      const std::size_t need = sizeof(SampleRunHeader) + (clear ? 0 : n * valueBytes);
      if (at + need > out.size())
        out.resize(at + std::max(need, std::min<std::size_t>(2048, samples.size() - i) * worst));
      const RaySample& first = samples[i];
      const SampleRunHeader h{first.pixel, static_cast<std::uint16_t>(first.k),
                              static_cast<std::uint16_t>(clear ? kTransparent + n : n)};
      std::memcpy(out.data() + at, &h, sizeof h);
      at += sizeof h;
      if (!clear) {
        if (wire == SampleWire::Half) {
          floatToHalf4Strided(valuesOf(&first), sizeof(RaySample), n, out.data() + at);
        } else {
          for (std::size_t j = 0; j < n; ++j) std::memcpy(out.data() + at + j * valueBytes, valuesOf(&first + j), valueBytes);
        }
        at += n * valueBytes;
      }
      i += n;
    }
  } catch (...) {
    out.resize(at);  // the whole runs written before the failure, no room after them
    throw;
  }
  out.resize(at);
}

bool decodeSampleRuns(std::span<const std::byte> in, SampleWire wire, std::vector<RaySample>& out,
                      std::size_t maxSamples) {
  const std::size_t valueBytes = sampleWireBytes(wire);
  // Every run checked, and the samples counted, before anything is written.
  std::size_t total = 0;
  for (std::size_t at = 0; at < in.size();) {
    SampleRunHeader h;
    if (in.size() - at < sizeof h) return false;
    std::memcpy(&h, in.data() + at, sizeof h);
    at += sizeof h;
    const bool clear = h.n >= kTransparent;
    const std::size_t n = clear ? h.n - kTransparent : h.n;
    if (n == 0 || static_cast<std::size_t>(h.k) + n - 1 > 0xffffu || (!clear && (in.size() - at) / valueBytes < n) ||
        total + n > maxSamples)
      return false;
    total += n;
    if (!clear) at += n * valueBytes;
  }
  std::size_t next = out.size();
  out.resize(next + total);  // zeroed: a transparent sample's values are +0.0
  for (std::size_t at = 0; at < in.size();) {
    SampleRunHeader h;
    std::memcpy(&h, in.data() + at, sizeof h);
    at += sizeof h;
    const bool clear = h.n >= kTransparent;
    const std::size_t n = clear ? h.n - kTransparent : h.n;
    RaySample* s = out.data() + next;
    for (std::size_t j = 0; j < n; ++j) {
      s[j].pixel = h.pixel;
      s[j].k = h.k + static_cast<std::uint32_t>(j);
    }
    if (!clear) {
      if (wire == SampleWire::Half) {
        halfToFloat4Strided(in.data() + at, n, valuesOf(s), sizeof(RaySample));
      } else {
        for (std::size_t j = 0; j < n; ++j) std::memcpy(valuesOf(s + j), in.data() + at + j * valueBytes, valueBytes);
      }
      at += n * valueBytes;
    }
    next += n;
  }
  return true;
}

}  // namespace pp5
