#include "core/sample_runs.hpp"

#include <cstring>

#include "core/error.hpp"
#include "core/half_float.hpp"

namespace pp5 {

namespace {

constexpr std::uint16_t kTransparent = 0x8000;
constexpr std::uint16_t kMaxRun = 0x7fff;

bool transparent(const RaySample& s) {
  const float v[4] = {s.r, s.g, s.b, s.a};
  std::uint32_t bits[4];
  std::memcpy(bits, v, sizeof bits);
  return (bits[0] | bits[1] | bits[2] | bits[3]) == 0;
}

void putValues(const RaySample& s, SampleWire w, std::byte* dst) {
  const float v[4] = {s.r, s.g, s.b, s.a};
  if (w == SampleWire::Float) {
    std::memcpy(dst, v, sizeof v);
    return;
  }
  const std::uint16_t h[4] = {floatToHalf(v[0]), floatToHalf(v[1]), floatToHalf(v[2]), floatToHalf(v[3])};
  std::memcpy(dst, h, sizeof h);
}

}  // namespace

void encodeSampleRuns(std::span<const RaySample> samples, SampleWire wire, std::vector<std::byte>& out) {
  const std::size_t valueBytes = sampleWireBytes(wire);
  std::size_t i = 0;
  while (i < samples.size()) {
    const RaySample& first = samples[i];
    PP5_CHECK_LE(first.k, 0xffffu);
    const bool clear = transparent(first);
    std::size_t n = 1;
    while (i + n < samples.size() && n < kMaxRun) {
      const RaySample& s = samples[i + n];
      if (s.pixel != first.pixel || s.k != first.k + n || transparent(s) != clear) break;
      ++n;
    }
    PP5_CHECK_LE(first.k + n - 1, 0xffffu);
    const SampleRunHeader h{first.pixel, static_cast<std::uint16_t>(first.k),
                            static_cast<std::uint16_t>(clear ? kTransparent + n : n)};
    const std::size_t at = out.size();
    out.resize(at + sizeof h + (clear ? 0 : n * valueBytes));
    std::memcpy(out.data() + at, &h, sizeof h);
    if (!clear)
      for (std::size_t j = 0; j < n; ++j) putValues(samples[i + j], wire, out.data() + at + sizeof h + j * valueBytes);
    i += n;
  }
}

bool decodeSampleRuns(std::span<const std::byte> in, SampleWire wire, std::vector<RaySample>& out,
                      std::size_t maxSamples) {
  const std::size_t valueBytes = sampleWireBytes(wire);
  const std::size_t had = out.size();
  std::size_t at = 0;
  bool ok = true;
  while (ok && at < in.size()) {
    SampleRunHeader h;
    if (in.size() - at < sizeof h) {
      ok = false;
      break;
    }
    std::memcpy(&h, in.data() + at, sizeof h);
    at += sizeof h;
    const bool clear = h.n >= kTransparent;
    const std::size_t n = clear ? h.n - kTransparent : h.n;
    if (n == 0 || static_cast<std::size_t>(h.k) + n - 1 > 0xffffu || (!clear && (in.size() - at) / valueBytes < n) ||
        out.size() - had + n > maxSamples) {
      ok = false;
      break;
    }
    const std::size_t base = out.size();
    out.resize(base + n);
    for (std::size_t j = 0; j < n; ++j) {
      RaySample& s = out[base + j];
      s.pixel = h.pixel;
      s.k = h.k + static_cast<std::uint32_t>(j);
      if (clear) {
        s.r = s.g = s.b = s.a = 0.0f;
        continue;
      }
      float v[4];
      if (wire == SampleWire::Float) {
        std::memcpy(v, in.data() + at, sizeof v);
      } else {
        std::uint16_t hv[4];
        std::memcpy(hv, in.data() + at, sizeof hv);
        for (int c = 0; c < 4; ++c) v[c] = halfToFloat(hv[c]);
      }
      at += valueBytes;
      s.r = v[0];
      s.g = v[1];
      s.b = v[2];
      s.a = v[3];
    }
  }
  if (!ok) {
    out.resize(had);
    return false;
  }
  return true;
}

}  // namespace pp5
