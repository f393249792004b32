// The samples' wire form (formats/sample_runs.hpp): what a PP decodes is what
// the GP encoded (float exactly; half exactly as the half cache stores it),
// transparent runs cost a header, and malformed input is refused.
#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <vector>

#include "core/half_float.hpp"
#include "formats/sample_runs.hpp"

namespace {

using namespace pp5;

// Rays of consecutive samples, some transparent in runs, some not, in
// scrambled ray order, with a few isolated samples.
std::vector<RaySample> someSamples(std::mt19937& rng) {
  std::vector<RaySample> s;
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (std::uint32_t ray = 0; ray < 40; ++ray) {
    const std::uint32_t pixel = (ray * 7919u) % 5000u;
    std::uint32_t k = std::uniform_int_distribution<std::uint32_t>(0, 60000)(rng);
    const int n = std::uniform_int_distribution<int>(1, 90)(rng);
    for (int i = 0; i < n; ++i, ++k) {
      const bool clear = (i / 7) % 2 == 0;
      const float a = clear ? 0.0f : u(rng);
      s.push_back({pixel, k, a * u(rng), a * u(rng), a * u(rng), a});
    }
    if (ray % 5 == 0) s.push_back({pixel + 1, 3, 0.25f, 0.5f, 0.125f, 0.75f});
  }
  return s;
}

// The wire byte for byte as the format's comment says, against an encoder
// written here the plain way (a run at a time, a value at a time): appended
// after bytes already in `out`, for both wires, and for a batch long enough
// that the encoder makes room for it more than once.
std::vector<std::byte> referenceWire(const std::vector<RaySample>& s, SampleWire w, std::vector<std::byte> out) {
  auto put = [&](const void* p, std::size_t n) {
    const auto* b = static_cast<const std::byte*>(p);
    out.insert(out.end(), b, b + n);
  };
  auto clearOf = [](const RaySample& x) {
    std::uint32_t bits[4];
    const float v[4] = {x.r, x.g, x.b, x.a};
    std::memcpy(bits, v, sizeof bits);
    return (bits[0] | bits[1] | bits[2] | bits[3]) == 0;
  };
  for (std::size_t i = 0; i < s.size();) {
    const bool clear = clearOf(s[i]);
    std::size_t n = 1;
    while (i + n < s.size() && n < 0x7fff && s[i + n].pixel == s[i].pixel && s[i + n].k == s[i].k + n &&
           clearOf(s[i + n]) == clear)
      ++n;
    const std::uint32_t pixel = s[i].pixel;
    const auto k = static_cast<std::uint16_t>(s[i].k), count = static_cast<std::uint16_t>(clear ? 0x8000 + n : n);
    put(&pixel, 4);
    put(&k, 2);
    put(&count, 2);
    for (std::size_t j = 0; j < n && !clear; ++j) {
      const float v[4] = {s[i + j].r, s[i + j].g, s[i + j].b, s[i + j].a};
      if (w == SampleWire::Float) {
        put(v, sizeof v);
      } else {
        for (const float x : v) {
          const std::uint16_t h = floatToHalf(x);
          put(&h, 2);
        }
      }
    }
    i += n;
  }
  return out;
}

TEST(SampleRuns, TheWireIsTheFormatsBytes) {
  std::mt19937 rng(11);
  std::vector<RaySample> in;
  while (in.size() < 20000) {  // several of the encoder's rooms
    const std::vector<RaySample> more = someSamples(rng);
    in.insert(in.end(), more.begin(), more.end());
  }
  for (int i = 0; i < 3000; ++i) in.push_back({7u, static_cast<std::uint32_t>(100 + i), 0.5f, 0.25f, 0.125f, 1.0f});
  for (const SampleWire w : {SampleWire::Half, SampleWire::Float}) {
    const std::vector<std::byte> before = {std::byte{1}, std::byte{2}, std::byte{3}};
    std::vector<std::byte> wire = before;
    encodeSampleRuns(in, w, wire);
    EXPECT_EQ(wire, referenceWire(in, w, before)) << (w == SampleWire::Half ? "half" : "float");
    std::vector<std::byte> empty = before;
    encodeSampleRuns({}, w, empty);
    EXPECT_EQ(empty, before);
  }
}

TEST(SampleRuns, FloatRoundTripsExactly) {
  std::mt19937 rng(3);
  const std::vector<RaySample> in = someSamples(rng);
  std::vector<std::byte> wire;
  encodeSampleRuns(in, SampleWire::Float, wire);
  std::vector<RaySample> out;
  ASSERT_TRUE(decodeSampleRuns(wire, SampleWire::Float, out));
  ASSERT_EQ(out.size(), in.size());
  EXPECT_EQ(std::memcmp(out.data(), in.data(), in.size() * sizeof(RaySample)), 0);
}

TEST(SampleRuns, HalfGivesTheBitsTheHalfCacheStores) {
  std::mt19937 rng(4);
  const std::vector<RaySample> in = someSamples(rng);
  std::vector<std::byte> wire;
  encodeSampleRuns(in, SampleWire::Half, wire);
  std::vector<RaySample> out;
  ASSERT_TRUE(decodeSampleRuns(wire, SampleWire::Half, out));
  ASSERT_EQ(out.size(), in.size());
  std::size_t clear = 0;
  for (std::size_t i = 0; i < in.size(); ++i) {
    ASSERT_EQ(out[i].pixel, in[i].pixel);
    ASSERT_EQ(out[i].k, in[i].k);
    const float a[4] = {in[i].r, in[i].g, in[i].b, in[i].a}, b[4] = {out[i].r, out[i].g, out[i].b, out[i].a};
    for (int c = 0; c < 4; ++c) ASSERT_EQ(floatToHalf(b[c]), floatToHalf(a[c])) << "sample " << i << " channel " << c;
    clear += in[i].a == 0.0f;
  }
  // Transparent samples cost nothing beyond their runs' headers; a visible
  // one costs its 8 bytes of values: far below 24 bytes a sample.
  const std::size_t visible = in.size() - clear;
  EXPECT_LT(wire.size(), visible * 8 + in.size() / 2 * sizeof(SampleRunHeader));
  EXPECT_LT(wire.size() * 2, in.size() * sizeof(RaySample));
}

TEST(SampleRuns, MalformedInputIsRefusedAndLeavesTheOutputAlone) {
  std::mt19937 rng(5);
  const std::vector<RaySample> in = someSamples(rng);
  std::vector<std::byte> wire;
  encodeSampleRuns(in, SampleWire::Half, wire);
  std::vector<RaySample> out(3);
  for (const std::size_t cut : {std::size_t{1}, std::size_t{5}, std::size_t{9}}) {
    std::vector<std::byte> part(wire.begin(), wire.end() - static_cast<std::ptrdiff_t>(cut));
    EXPECT_FALSE(decodeSampleRuns(part, SampleWire::Half, out)) << cut;
    EXPECT_EQ(out.size(), 3u);
  }
  // A run that claims no samples, or runs past k = 65535.
  SampleRunHeader h{1, 10, 0};
  std::vector<std::byte> bad(sizeof h);
  std::memcpy(bad.data(), &h, sizeof h);
  EXPECT_FALSE(decodeSampleRuns(bad, SampleWire::Float, out));
  h = {1, 65535, 0x8000 + 2};
  std::memcpy(bad.data(), &h, sizeof h);
  EXPECT_FALSE(decodeSampleRuns(bad, SampleWire::Float, out));
  EXPECT_EQ(out.size(), 3u);
  // More samples than the message may hold: refused before anything is made
  // (a transparent run's 8 bytes claim 32767 samples).
  h = {1, 0, 0x8000 + 0x7fff};
  std::memcpy(bad.data(), &h, sizeof h);
  EXPECT_FALSE(decodeSampleRuns(bad, SampleWire::Half, out, 1000));
  EXPECT_TRUE(decodeSampleRuns(bad, SampleWire::Half, out, 0x7fff));
  EXPECT_EQ(out.size(), 3u + 0x7fff);
  out.resize(3);
  // Empty input is no samples.
  EXPECT_TRUE(decodeSampleRuns({}, SampleWire::Half, out));
  EXPECT_EQ(out.size(), 3u);
}

}  // namespace
