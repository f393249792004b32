// The pixel processor's ray-sample cache: analytic composites, incremental
// == from-scratch bit for bit, dirty tracking, tiles, the storage format's
// error (the figures behind the default), options.
#include <gtest/gtest.h>
#include <sys/resource.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "core/config.hpp"
#include "core/error.hpp"
#include "core/half_float.hpp"
#include "rendering/ray_cache.hpp"

namespace {

using pp5::RaySample;
using pp5::pp::CompositeMode;
using pp5::pp::RayCache;
using pp5::pp::RayCacheSettings;
using pp5::pp::SampleFormat;
using pp5::pp::TileImage;
using pp5::TileRect;

RayCacheSettings settingsFor(SampleFormat f, int blockSize = 32, bool termination = true) {
  RayCacheSettings s;
  s.format = f;
  s.blockSize = blockSize;
  s.earlyTermination = termination;
  return s;
}

// Premultiplied sample of opacity a and a grey-ish colour.
RaySample sample(std::uint32_t pixel, std::uint32_t k, float a, float grey = 0.8f) {
  RaySample s;
  s.pixel = pixel;
  s.k = k;
  s.a = a;
  s.r = a * grey;
  s.g = a * grey * 0.9f;
  s.b = a * grey * 0.7f;
  return s;
}

bool sameBits(const TileImage& x, const TileImage& y) {
  return x.width == y.width && x.height == y.height && x.rgba.size() == y.rgba.size() &&
         std::memcmp(x.rgba.data(), y.rgba.data(), x.rgba.size() * sizeof(float)) == 0;
}

// A stored value read back: what the format keeps of v.
float quantised(SampleFormat f, float v) {
  switch (f) {
    case SampleFormat::Rgba8: return std::round(std::clamp(v, 0.0f, 1.0f) * 255.0f) * (1.0f / 255.0f);
    case SampleFormat::Half: return pp5::halfToFloat(pp5::floatToHalf(v));
    case SampleFormat::Float: return v;
  }
  return v;
}

const SampleFormat kFormats[] = {SampleFormat::Rgba8, SampleFormat::Half, SampleFormat::Float};
const CompositeMode kModes[] = {CompositeMode::Over, CompositeMode::Additive, CompositeMode::Mip};

// ---------------------------------------------------------------------------
// Half conversions: bit-identical to GCC's _Float16.

TEST(HalfFloat, HalfToFloatMatchesFloat16ForEveryHalf) {
  for (std::uint32_t h = 0; h < 65536; ++h) {
    _Float16 x;
    const auto hh = static_cast<std::uint16_t>(h);
    std::memcpy(&x, &hh, 2);
    const float want = static_cast<float>(x), got = pp5::halfToFloat(hh);
    if (std::isnan(want)) {
      ASSERT_TRUE(std::isnan(got)) << h;
      continue;
    }
    std::uint32_t a, b;
    std::memcpy(&a, &want, 4);
    std::memcpy(&b, &got, 4);
    ASSERT_EQ(a, b) << "half 0x" << std::hex << h;
  }
}

TEST(HalfFloat, FloatToHalfRoundsAsFloat16) {
  auto check = [](std::uint32_t u) {
    float f;
    std::memcpy(&f, &u, 4);
    const _Float16 x = static_cast<_Float16>(f);
    std::uint16_t want;
    std::memcpy(&want, &x, 2);
    const std::uint16_t got = pp5::floatToHalf(f);
    if (std::isnan(f)) return (got & 0x7c00u) == 0x7c00u && (got & 0x3ffu) != 0;
    return got == want;
  };
  // A stride through every float, then every float around half's range
  // boundaries and the rounding of small opacities, where the cases live.
  for (std::uint64_t u = 0; u < (1ull << 32); u += 997) ASSERT_TRUE(check(static_cast<std::uint32_t>(u))) << u;
  for (std::uint32_t base : {0x33000000u, 0x38800000u, 0x3b000000u, 0x3c000000u, 0x477fe000u, 0x7f800000u})
    for (std::uint32_t d = 0; d < (1u << 20); ++d) {
      ASSERT_TRUE(check(base - (1u << 19) + d)) << std::hex << base - (1u << 19) + d;
      ASSERT_TRUE(check((base - (1u << 19) + d) | 0x80000000u));
    }
}

// The batch conversions (F16C where the CPU has it) give the scalar bits.
TEST(HalfFloat, BatchConversionsMatchScalar) {
  std::vector<std::uint16_t> h(65536);
  for (std::uint32_t i = 0; i < 65536; ++i) h[i] = static_cast<std::uint16_t>(i);
  std::vector<float> f(h.size());
  pp5::halfToFloatN(h.data(), h.size(), f.data());
  for (std::uint32_t i = 0; i < 65536; ++i) {
    const float want = pp5::halfToFloat(h[i]);
    if (std::isnan(want)) {
      ASSERT_TRUE(std::isnan(f[i]));
      continue;
    }
    ASSERT_EQ(std::memcmp(&want, &f[i], 4), 0) << i;
  }
  std::vector<float> in;
  for (std::uint64_t u = 0; u < (1ull << 32); u += 1021) {
    const auto v = static_cast<std::uint32_t>(u);
    float x;
    std::memcpy(&x, &v, 4);
    if (!std::isnan(x)) in.push_back(x);
  }
  std::vector<std::uint16_t> out(in.size() + 5);
  pp5::floatToHalfN(in.data(), in.size(), out.data());
  for (std::size_t i = 0; i < in.size(); ++i) ASSERT_EQ(out[i], pp5::floatToHalf(in[i])) << in[i];
  std::printf("half conversions use F16C: %s\n", pp5::halfConversionUsesF16c() ? "yes" : "no");
}

// The strided four-value conversions (a sample's r g b a in a struct, to and
// from the wire's packed halves) give the scalar bits too, groups at any stride.
TEST(HalfFloat, StridedGroupsOfFourMatchScalar) {
  constexpr std::size_t kStride = 6;  // floats: RaySample's size
  std::vector<float> in;
  for (std::uint64_t u = 0; u < (1ull << 32); u += 4099) {
    const auto v = static_cast<std::uint32_t>(u);
    float x;
    std::memcpy(&x, &v, 4);
    if (!std::isnan(x)) in.push_back(x);
  }
  // NaNs too, quiet and signalling, of either sign: a NaN half comes back a NaN.
  for (const std::uint32_t nan : {0x7fc00000u, 0xffc00001u, 0x7f800001u, 0xff812345u}) {
    float x;
    std::memcpy(&x, &nan, 4);
    in.push_back(x);
  }
  while (in.size() % 4) in.push_back(1.0f);
  const std::size_t groups = in.size() / 4;
  std::vector<float> strided(groups * kStride, -7.0f);
  for (std::size_t g = 0; g < groups; ++g)
    for (std::size_t c = 0; c < 4; ++c) strided[g * kStride + c] = in[g * 4 + c];
  std::vector<std::uint16_t> halves(groups * 4 + 4, 0xabcd);
  pp5::floatToHalf4Strided(strided.data(), kStride * sizeof(float), groups, halves.data());
  for (std::size_t i = 0; i < groups * 4; ++i) ASSERT_EQ(halves[i], pp5::floatToHalf(in[i])) << in[i];
  EXPECT_EQ(halves[groups * 4], 0xabcd);  // nothing written past the last group
  std::vector<float> back(groups * kStride, -7.0f);
  pp5::halfToFloat4Strided(halves.data(), groups, back.data(), kStride * sizeof(float));
  for (std::size_t g = 0; g < groups; ++g) {
    for (std::size_t c = 0; c < 4; ++c) {
      const float want = pp5::halfToFloat(halves[g * 4 + c]);
      if (std::isnan(want)) {  // F16C quiets a signalling NaN (half_float.hpp)
        ASSERT_TRUE(std::isnan(back[g * kStride + c])) << g;
        continue;
      }
      ASSERT_EQ(std::memcmp(&want, &back[g * kStride + c], 4), 0) << g;
    }
    ASSERT_EQ(back[g * kStride + 4], -7.0f);  // the struct's other fields are left alone
    ASSERT_EQ(back[g * kStride + 5], -7.0f);
  }
}

// ---------------------------------------------------------------------------
// Analytic composites.

struct Analytic : ::testing::TestWithParam<SampleFormat> {};

TEST_P(Analytic, UniformRunOverAdditiveMip) {
  const SampleFormat f = GetParam();
  const int n = 300;
  const float a = 0.01f, grey = 0.6f;
  const std::vector<std::uint16_t> counts = {static_cast<std::uint16_t>(n)};
  RayCacheSettings s = settingsFor(f, 16, false);
  s.additiveScale = 0.2;
  std::vector<RaySample> run;
  for (int k = 0; k < n; ++k) run.push_back(sample(0, static_cast<std::uint32_t>(k), a, grey));

  // What the format keeps of the sample, then exact arithmetic on it: the
  // float composite of 300 samples stays within 2e-5 of it.
  const double aq = quantised(f, run[0].a), rq = quantised(f, run[0].r);
  const double alpha = 1.0 - std::pow(1.0 - aq, n);
  const double colour = rq * (1.0 - std::pow(1.0 - aq, n)) / aq;
  const double tol = 2e-5;

  RayCache over(TileRect{0, 0, 1, 1}, 1, counts, s, CompositeMode::Over);
  over.put(run.data(), run.size());
  over.composite();
  EXPECT_NEAR(over.image().rgba[3], alpha, tol);
  EXPECT_NEAR(over.image().rgba[0], colour, tol);
  // Against the exact opacity, the format's rounding counts: half keeps a
  // relative 2^-12, which moves alpha by at most 2^-12 / e and the colour by
  // 2^-12 (3e-4 covers both); rgba8 stores 0.01 as 3/255.
  const double exactAlpha = 1.0 - std::pow(1.0 - a, n);
  const double exactError = std::abs(over.image().rgba[3] - exactAlpha);
  EXPECT_LT(exactError, f == SampleFormat::Half ? 3e-4 : f == SampleFormat::Float ? tol : 1.0);
  if (f == SampleFormat::Rgba8) {
    EXPECT_GT(exactError, 0.015);
  }

  // Additive and MIP read grey-value samples (r = g = b = v / 255, a = v /
  // 255 times the step): additive shows the sum of a times the scale, MIP the
  // largest r, each through the value window, as premultiplied white.
  RayCache add(TileRect{0, 0, 1, 1}, 1, counts, s, CompositeMode::Additive);
  add.put(run.data(), run.size());
  add.composite();
  const double sum = 0.2 * n * aq;  // 0.6: inside the identity window
  for (int c = 0; c < 4; ++c) EXPECT_NEAR(add.image().rgba[c], sum, sum * 1e-5) << c;
  add.setValueWindow(0.25 * 255, 0.75 * 255);
  add.composite();
  EXPECT_NEAR(add.image().rgba[0], (sum - 0.25) / 0.5, 1e-5);

  // MIP of a run with one brighter sample is that sample's r, as stored.
  run[137] = sample(0, 137, 0.04f, 0.9f);
  RayCache mip(TileRect{0, 0, 1, 1}, 1, counts, s, CompositeMode::Mip);
  mip.put(run.data(), run.size());
  mip.composite();
  const double top = quantised(f, run[137].r);
  for (int c = 0; c < 4; ++c) EXPECT_NEAR(mip.image().rgba[c], top, 1e-6) << c;
  EXPECT_THROW(mip.setValueWindow(-1.0, 255.0), pp5::InputError);
  EXPECT_THROW(mip.setValueWindow(100.0, 100.0), pp5::InputError);
}

TEST_P(Analytic, EarlyTerminationStopsWithinOneMinusThreshold) {
  const SampleFormat f = GetParam();
  const int n = 512;
  const float a = 0.05f;
  const std::vector<std::uint16_t> counts = {static_cast<std::uint16_t>(n)};
  std::vector<RaySample> run;
  for (int k = 0; k < n; ++k) run.push_back(sample(0, static_cast<std::uint32_t>(k), a));
  RayCacheSettings s = settingsFor(f, 8, true);
  RayCache c(TileRect{0, 0, 1, 1}, 1, counts, s);
  c.put(run.data(), run.size());
  const auto st = c.composite();
  const double aq = quantised(f, a);
  const double alpha = c.image().rgba[3];
  EXPECT_GE(alpha, s.terminationAlpha - 1e-6);
  EXPECT_LE(alpha, 1.0 - std::pow(1.0 - aq, n) + 1e-6);
  // Terminated at the first block boundary past the threshold, not at the end.
  const int blocksNeeded = static_cast<int>(std::ceil(std::log(1.0 - s.terminationAlpha) / std::log(1.0 - aq) / 8));
  EXPECT_NEAR(static_cast<double>(st.blocks), blocksNeeded, 1.0);
  EXPECT_LT(st.blocks, static_cast<std::uint64_t>(n / 8));
}

INSTANTIATE_TEST_SUITE_P(Formats, Analytic, ::testing::ValuesIn(kFormats),
                         [](const auto& i) { return std::string(pp5::pp::sampleFormatName(i.param)); });

// ---------------------------------------------------------------------------
// Incremental == from scratch, bit for bit.

struct IncCase {
  CompositeMode mode;
  SampleFormat format;
  bool termination;
  int blockSize;
};

std::string incName(const ::testing::TestParamInfo<IncCase>& i) {
  return std::string(pp5::pp::compositeModeName(i.param.mode)) + "_" + pp5::pp::sampleFormatName(i.param.format) +
         (i.param.termination ? "_term" : "_noterm") + "_b" + std::to_string(i.param.blockSize);
}

std::vector<IncCase> incCases() {
  std::vector<IncCase> v;
  for (auto m : kModes)
    for (auto f : kFormats)
      for (bool t : {true, false})
        for (int b : {1, 8, 32}) v.push_back({m, f, t, b});
  return v;
}

struct Incremental : ::testing::TestWithParam<IncCase> {};

TEST_P(Incremental, EqualsFromScratchAfterEveryBatch) {
  const IncCase p = GetParam();
  const TileRect tile{7, 5, 23, 19};
  const int imageWidth = 41;
  const RayCacheSettings s = settingsFor(p.format, p.blockSize, p.termination);
  std::mt19937 rng(1990u + static_cast<unsigned>(p.blockSize));
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);

  const int nrays = tile.width * tile.height;
  std::vector<std::uint16_t> counts(nrays);
  for (auto& c : counts) {
    const float r = u01(rng);
    c = static_cast<std::uint16_t>(r < 0.1f ? 0 : r < 0.2f ? 1 + rng() % 7 : 20 + rng() % 180);
  }
  auto pixelOf = [&](int local) {
    return static_cast<std::uint32_t>((tile.y0 + local / tile.width) * imageWidth + tile.x0 + local % tile.width);
  };
  // The final value of every sample ever put, for the from-scratch cache.
  std::vector<std::vector<RaySample>> truth(nrays);
  std::vector<std::vector<char>> seen(nrays);
  for (int i = 0; i < nrays; ++i) {
    truth[i].resize(counts[i]);
    seen[i].assign(counts[i], 0);
  }

  RayCache inc(tile, imageWidth, counts, s, p.mode, 2);
  std::uint64_t lazyBlocks = 0;
  for (int batch = 0; batch < 40; ++batch) {
    std::vector<RaySample> put;
    auto add = [&](int local, int k, float a) {
      if (k < 0 || k >= counts[local]) return;
      RaySample smp = sample(pixelOf(local), static_cast<std::uint32_t>(k), a, 0.2f + 0.8f * u01(rng));
      put.push_back(smp);
      truth[local][k] = smp;
      seen[local][k] = 1;
    };
    const int kind = batch < 2 ? 0 : static_cast<int>(rng() % 5);
    if (kind == 0) {  // every sample of every ray: a full render, some rays opaque early
      for (int i = 0; i < nrays; ++i) {
        const float dense = u01(rng) < 0.4f ? 0.3f : 0.0f;
        for (int k = 0; k < counts[i]; ++k) add(i, k, dense + 0.002f + 0.048f * u01(rng));
      }
    } else if (kind == 1) {  // scattered samples
      for (int j = 0; j < 200; ++j) {
        const int i = static_cast<int>(rng() % nrays);
        add(i, static_cast<int>(rng() % 200), u01(rng) < 0.2f ? u01(rng) : 0.05f * u01(rng));
      }
    } else if (kind == 2) {  // a slab: a band of pixels, a range of k
      const int x0 = static_cast<int>(rng() % tile.width), k0 = static_cast<int>(rng() % 150);
      for (int y = 0; y < tile.height; ++y)
        for (int x = x0; x < std::min(tile.width, x0 + 6); ++x)
          for (int k = k0 + y; k < k0 + y + 16; ++k) add(y * tile.width + x, k, 0.05f * u01(rng));
    } else if (kind == 3) {  // behind the termination point: the back of rays
      for (int i = 0; i < nrays; ++i)
        if (rng() % 3 == 0)
          for (int k = counts[i] / 2; k < counts[i]; k += 3) add(i, k, 0.9f * u01(rng));
    } else {  // the front made transparent, so what was behind becomes visible
      for (int i = 0; i < nrays; ++i)
        if (rng() % 2 == 0)
          for (int k = 0; k < std::min<int>(counts[i], 40); ++k) add(i, k, 0.0f);
    }
    std::shuffle(put.begin(), put.end(), rng);
    // A batch may hold one sample twice; the later one wins, in truth too.
    inc.put(put.data(), put.size());
    for (const RaySample& smp : put) {
      const int local = static_cast<int>((smp.pixel / imageWidth - tile.y0) * tile.width + smp.pixel % imageWidth - tile.x0);
      truth[local][smp.k] = smp;
    }
    const auto before = inc.counters();
    inc.composite();
    lazyBlocks += inc.counters().blocksComposited - before.blocksComposited;

    std::vector<RaySample> all;
    for (int i = 0; i < nrays; ++i)
      for (int k = 0; k < counts[i]; ++k)
        if (seen[i][k]) all.push_back(truth[i][k]);
    RayCache fresh(tile, imageWidth, counts, s, p.mode, 1);
    fresh.put(all.data(), all.size());
    fresh.composite();
    ASSERT_TRUE(sameBits(inc.image(), fresh.image())) << "batch " << batch << " kind " << kind;
    ASSERT_TRUE(sameBits(inc.compositeFull(p.mode), inc.image())) << "batch " << batch;
    if (batch % 8 == 7) {
      for (auto m : kModes) ASSERT_TRUE(sameBits(inc.compositeFull(m), fresh.compositeFull(m))) << batch;
    }
    if (p.mode == CompositeMode::Over && p.termination && kind == 0) {
      EXPECT_LT(fresh.counters().blocksComposited, fresh.blockCount()) << "termination never happened";
    }
  }
  EXPECT_GT(lazyBlocks, 0u);
}

INSTANTIATE_TEST_SUITE_P(All, Incremental, ::testing::ValuesIn(incCases()), incName);

// The arithmetic of a block, pinned down (the MPI runs must reproduce it bit
// for bit): four runs, lanes 0..2 of n/4 samples and lane 3 the rest, each
// folded front to back from the identity, then the lanes folded in order;
// "over" carries transmittance, r += T * s.r, T *= 1 - s.a, alpha = 1 - T.
TEST(Incremental, BlockArithmeticIsTheDocumentedOrder) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 0.2f);
  for (auto m : kModes)
    for (int n = 1; n <= 45; ++n) {
      std::vector<RaySample> ray;
      for (int k = 0; k < n; ++k) ray.push_back(sample(0, static_cast<std::uint32_t>(k), u(rng), 0.5f + u(rng)));
      RayCacheSettings s = settingsFor(SampleFormat::Float, 64, false);
      s.additiveScale = 0.01;
      RayCache c(TileRect{0, 0, 1, 1}, 1, std::vector<std::uint16_t>{static_cast<std::uint16_t>(n)}, s, m);
      c.put(ray.data(), ray.size());
      c.composite();

      struct P {
        float r, g, b, w;
      };
      auto fold = [m](P& acc, float r, float g, float b, float w) {
        if (m == CompositeMode::Over) {
          acc.r += acc.w * r;
          acc.g += acc.w * g;
          acc.b += acc.w * b;
          acc.w *= w;
        } else if (m == CompositeMode::Additive) {
          acc.r += r;
          acc.g += g;
          acc.b += b;
          acc.w += w;
        } else {
          acc.r = r > acc.r ? r : acc.r;
          acc.g = g > acc.g ? g : acc.g;
          acc.b = b > acc.b ? b : acc.b;
          acc.w = w > acc.w ? w : acc.w;
        }
      };
      const P id = m == CompositeMode::Over ? P{0, 0, 0, 1} : P{0, 0, 0, 0};
      P lane[4] = {id, id, id, id};
      const int q = n / 4;
      for (int j = 0; j < 4; ++j)
        for (int k = j * q; k < (j == 3 ? n : (j + 1) * q); ++k) {
          const RaySample& x = ray[k];
          fold(lane[j], x.r, x.g, x.b, m == CompositeMode::Over ? 1.0f - x.a : x.a);
        }
      P acc = lane[0];
      for (int j = 1; j < 4; ++j) fold(acc, lane[j].r, lane[j].g, lane[j].b, lane[j].w);
      float want[4] = {acc.r, acc.g, acc.b, 1.0f - acc.w};
      if (m != CompositeMode::Over) {  // grey: the largest r, or the sum of a times the scale, windowed [0, 255]
        const float grey = m == CompositeMode::Mip ? acc.r * 255.0f : acc.w * 255.0f * 0.01f;
        const float v = std::min(1.0f, std::max(0.0f, (grey - 0.0f) * (1.0f / 255.0f)));
        for (float& x : want) x = v;
      }
      ASSERT_EQ(std::memcmp(want, c.image().pixel(0, 0), 16), 0) << pp5::pp::compositeModeName(m) << " n " << n;
    }
}

// A change behind the termination point costs nothing until the front turns
// transparent; then the lazily kept block is composited and shows.
TEST(Incremental, BehindTerminationIsLazyUntilReachable) {
  for (auto f : kFormats) {
    const std::vector<std::uint16_t> counts = {64, 64};
    const RayCacheSettings s = settingsFor(f, 8, true);
    RayCache c(TileRect{0, 0, 2, 1}, 2, counts, s);
    std::vector<RaySample> front;
    for (std::uint32_t k = 0; k < 8; ++k) front.push_back(sample(0, k, 1.0f));
    c.put(front.data(), front.size());
    auto st = c.composite();
    EXPECT_EQ(st.rays, 1u);
    EXPECT_EQ(st.blocks, 1u);
    const TileImage opaque = c.image();

    const RaySample back = sample(0, 42, 0.5f, 0.3f);
    c.put(&back, 1);
    st = c.composite();
    EXPECT_EQ(st.rays, 0u) << "a change behind the termination point recomposited its ray";
    EXPECT_EQ(st.blocks, 0u);
    EXPECT_TRUE(sameBits(c.image(), opaque));

    for (auto& smp : front) smp.r = smp.g = smp.b = smp.a = 0.0f;
    c.put(front.data(), front.size());
    st = c.composite();
    EXPECT_EQ(st.rays, 1u);
    EXPECT_EQ(st.blocks, 2u) << "block 0 and the lazily kept block 5";
    EXPECT_EQ(c.image().rgba[3], quantised(f, 0.5f));
    EXPECT_EQ(c.image().rgba[0], quantised(f, back.r));

    RayCache fresh(TileRect{0, 0, 2, 1}, 2, counts, s);
    fresh.put(front.data(), front.size());
    fresh.put(&back, 1);
    fresh.composite();
    EXPECT_TRUE(sameBits(c.image(), fresh.image()));
  }
}

TEST(Incremental, SameBitsForAnyThreadCount) {
  const TileRect tile{0, 0, 64, 48};
  std::vector<std::uint16_t> counts(static_cast<std::size_t>(tile.width) * tile.height);
  std::mt19937 rng(7);
  for (auto& c : counts) c = static_cast<std::uint16_t>(rng() % 300);
  std::vector<RaySample> all;
  std::uniform_real_distribution<float> a(0.0f, 0.08f);
  for (std::size_t i = 0; i < counts.size(); ++i)
    for (std::uint32_t k = 0; k < counts[i]; ++k) all.push_back(sample(static_cast<std::uint32_t>(i), k, a(rng)));
  for (auto m : kModes) {
    std::vector<TileImage> images;
    for (int threads : {1, 2, 3, 0}) {
      RayCache c(tile, tile.width, counts, RayCacheSettings{}, m, threads);
      c.put(all.data(), all.size());
      c.composite();
      images.push_back(c.image());
      images.push_back(c.compositeFull(CompositeMode::Mip));
    }
    for (std::size_t i = 2; i < images.size(); ++i) EXPECT_TRUE(sameBits(images[i], images[i % 2])) << i;
  }
}

// A new view reuses the storage and zeroes only the pages the last view
// wrote: after reset() (to other counts, smaller and larger) or clear(), the
// cache gives the bits of a new cache given the same samples.
TEST(Reset, ReusedStorageEqualsANewCache) {
  const TileRect tile{0, 0, 40, 30};
  const std::size_t n = static_cast<std::size_t>(tile.width) * tile.height;
  std::mt19937 rng(11);
  auto randomCounts = [&](unsigned most) {
    std::vector<std::uint16_t> counts(n);
    for (auto& c : counts) c = static_cast<std::uint16_t>(rng() % most);
    return counts;
  };
  // About a third of the rays get a run of visible samples.
  auto someSamples = [&](const std::vector<std::uint16_t>& counts) {
    std::vector<RaySample> out;
    std::uniform_real_distribution<float> a(0.001f, 0.2f);
    for (std::size_t i = 0; i < n; ++i) {
      if (counts[i] == 0 || rng() % 3 != 0) continue;
      const std::uint32_t k0 = rng() % counts[i], len = 1 + rng() % 40;
      for (std::uint32_t k = k0; k < std::min<std::uint32_t>(counts[i], k0 + len); ++k)
        out.push_back(sample(static_cast<std::uint32_t>(i), k, a(rng)));
    }
    return out;
  };
  for (auto f : kFormats)
    for (auto m : kModes) {
      std::vector<std::uint16_t> counts = randomCounts(300);
      RayCache reused(tile, tile.width, counts, settingsFor(f), m);
      for (const unsigned most : {300u, 100u, 500u, 0u}) {
        const std::vector<RaySample> before = someSamples(counts);
        reused.put(before);
        reused.composite();
        if (most == 0) {
          reused.clear();  // same counts, every sample transparent again
        } else {
          counts = randomCounts(most);
          reused.reset(counts);
        }
        const std::vector<RaySample> after = someSamples(counts);
        RayCache fresh(tile, tile.width, counts, settingsFor(f), m);
        fresh.put(after);
        reused.put(after);
        fresh.composite();
        reused.composite();
        EXPECT_TRUE(sameBits(reused.image(), fresh.image())) << pp5::pp::sampleFormatName(f) << " " << most;
        for (auto other : kModes)
          EXPECT_TRUE(sameBits(reused.compositeFull(other), fresh.compositeFull(other)))
              << pp5::pp::sampleFormatName(f) << " " << most;
      }
    }
}

// Threads that each put their own rays, each into its own lane, at once (as
// the sampler's threads do on a new view): the cache composites the bits of
// one put of all the samples, counts every sample, and after a reset the
// lanes start empty. Neighbouring rays go to different threads, so that they
// share touched-page flags.
TEST(Lanes, ThreadsPuttingTheirOwnRaysEqualOnePut) {
  const TileRect tile{0, 0, 48, 20};
  const std::size_t n = static_cast<std::size_t>(tile.width) * tile.height;
  std::mt19937 rng(23);
  std::vector<std::uint16_t> counts(n);
  for (auto& c : counts) c = static_cast<std::uint16_t>(rng() % 200);
  std::vector<RaySample> all;
  std::uniform_real_distribution<float> a(0.001f, 0.1f);
  for (std::size_t i = 0; i < n; ++i)
    for (std::uint32_t k = 0; k < counts[i]; ++k)
      if (rng() % 4 == 0) all.push_back(sample(static_cast<std::uint32_t>(i), k, a(rng)));
  constexpr int kThreads = 3;
  for (auto f : kFormats)
    for (auto m : kModes) {
      RayCache one(tile, tile.width, counts, settingsFor(f), m), lanes(tile, tile.width, counts, settingsFor(f), m);
      lanes.setPutLanes(kThreads);
      for (int round = 0; round < 2; ++round) {
        one.put(all);
        std::vector<std::thread> threads;
        for (int t = 0; t < kThreads; ++t)
          threads.emplace_back([&, t] {
            // Batches of up to 50 samples of this thread's rays (pixel % 3 == t).
            std::vector<RaySample> batch;
            for (const RaySample& x : all) {
              if (static_cast<int>(x.pixel % kThreads) != t) continue;
              batch.push_back(x);
              if (batch.size() == 50) {
                lanes.put(t, batch.data(), batch.size());
                batch.clear();
              }
            }
            lanes.put(t, batch.data(), batch.size());
          });
        for (auto& th : threads) th.join();
        const auto st1 = one.composite(), st2 = lanes.composite();
        EXPECT_EQ(st2.rays, st1.rays);
        EXPECT_EQ(st2.blocks, st1.blocks);
        EXPECT_TRUE(sameBits(lanes.image(), one.image())) << pp5::pp::sampleFormatName(f) << " round " << round;
        EXPECT_EQ(lanes.counters().samplesPut, one.counters().samplesPut);
        // A new view: nothing listed is carried over, and the storage is clean.
        one.reset(counts);
        lanes.reset(counts);
        EXPECT_EQ(lanes.composite().rays, 0u);
      }
    }
  RayCache c(tile, tile.width, counts, RayCacheSettings{});
  EXPECT_THROW(c.put(0, all.data(), 1), pp5::InvariantError);  // no lanes set
}

// A coarse view's pixel stride: the strided pixels (image x and y multiples
// of it) take samples, and every pixel shows its block's strided pixel, the
// ones before a tile's first strided column or row its first; composite()
// reports the blocks it rewrote, and compositeFull() fills the same way.
TEST(Stride, EachPixelShowsItsBlocksStridedPixel) {
  const TileRect tile{5, 3, 13, 10};  // starts between strided pixels of stride 4
  const int imageWidth = 40, stride = 4;
  std::vector<std::uint16_t> counts(static_cast<std::size_t>(tile.width) * tile.height, 0);
  std::vector<RaySample> all;
  for (int y = 0; y < tile.height; ++y)
    for (int x = 0; x < tile.width; ++x) {
      const int gx = tile.x0 + x, gy = tile.y0 + y;
      if (gx % stride != 0 || gy % stride != 0) continue;
      counts[static_cast<std::size_t>(y) * tile.width + x] = 8;
      const auto pixel = static_cast<std::uint32_t>(gy * imageWidth + gx);
      for (std::uint32_t k = 0; k < 8; ++k) all.push_back(sample(pixel, k, 0.01f * static_cast<float>(1 + gx + gy)));
    }
  RayCache c(tile, imageWidth, counts, settingsFor(SampleFormat::Float));
  c.setPixelStride(stride);
  c.put(all);
  const auto st = c.composite();
  EXPECT_EQ(st.changed.x0, 0);
  EXPECT_EQ(st.changed.y0, 0);
  EXPECT_EQ(st.changed.width, tile.width);
  EXPECT_EQ(st.changed.height, tile.height);
  // The tile-local pixel a local column or row shows.
  auto source = [&](int origin, int local) {
    const int g = origin + local, own = g - g % stride;
    return own >= origin ? own - origin : (stride - origin % stride) % stride;
  };
  const TileImage full = c.compositeFull(CompositeMode::Over);
  for (int y = 0; y < tile.height; ++y)
    for (int x = 0; x < tile.width; ++x) {
      const int sx = source(tile.x0, x), sy = source(tile.y0, y);
      ASSERT_EQ((tile.x0 + sx) % stride, 0);
      ASSERT_GT(c.image().pixel(sx, sy)[3], 0.0f);
      EXPECT_EQ(std::memcmp(c.image().pixel(x, y), c.image().pixel(sx, sy), 16), 0) << x << " " << y;
      EXPECT_EQ(std::memcmp(full.pixel(x, y), c.image().pixel(x, y), 16), 0) << x << " " << y;
    }
  // One strided ray changes: its block only.
  const RaySample one = sample(static_cast<std::uint32_t>(8 * imageWidth + 12), 2, 0.3f);
  c.put(&one, 1);
  const auto st2 = c.composite();
  EXPECT_EQ(st2.changed.x0, 12 - tile.x0);
  EXPECT_EQ(st2.changed.y0, 8 - tile.y0);
  EXPECT_EQ(st2.changed.width, stride);
  EXPECT_EQ(st2.changed.height, stride);
}

// ---------------------------------------------------------------------------
// Dirty tracking.

TEST(DirtyTracking, CompositeWithoutPutTouchesNothing) {
  const TileRect tile{0, 0, 16, 16};
  std::vector<std::uint16_t> counts(256, 100);
  RayCache c(tile, 16, counts, RayCacheSettings{});
  std::vector<RaySample> all;
  for (std::uint32_t p = 0; p < 256; ++p)
    for (std::uint32_t k = 0; k < 100; ++k) all.push_back(sample(p, k, 0.01f));
  c.put(all.data(), all.size());
  auto st = c.composite();
  EXPECT_EQ(st.rays, 256u);
  EXPECT_EQ(st.blocks, 256u * 4u);  // 100 samples in blocks of 32
  EXPECT_EQ(st.changed.width, 16);
  const TileImage before = c.image();
  const auto counters = c.counters();

  st = c.composite();
  EXPECT_EQ(st.rays, 0u);
  EXPECT_EQ(st.blocks, 0u);
  EXPECT_TRUE(st.changed.empty());
  EXPECT_TRUE(sameBits(c.image(), before));
  EXPECT_EQ(c.counters().blocksComposited, counters.blocksComposited);
  EXPECT_EQ(c.counters().raysComposited, counters.raysComposited);
  EXPECT_EQ(c.counters().composites, counters.composites + 1);

  // One sample: one block of one ray, one pixel rewritten.
  const RaySample one = sample(5 * 16 + 9, 70, 0.02f);
  c.put(&one, 1);
  st = c.composite();
  EXPECT_EQ(st.rays, 1u);
  EXPECT_EQ(st.blocks, 1u);
  EXPECT_EQ(st.changed.x0, 9);
  EXPECT_EQ(st.changed.y0, 5);
  EXPECT_EQ(st.changed.width, 1);
  EXPECT_EQ(st.changed.height, 1);
  for (int i = 0; i < 256; ++i) {
    if (i != 5 * 16 + 9) {
      EXPECT_EQ(std::memcmp(c.image().pixel(i % 16, i / 16), before.pixel(i % 16, i / 16), 16), 0);
    }
  }
}

// ---------------------------------------------------------------------------
// Tiles.

TEST(Tiles, OffsetTileMapsPixelsAndRefusesOthers) {
  const TileRect tile{37, 21, 19, 13};
  const int imageWidth = 100;
  std::vector<std::uint16_t> counts(static_cast<std::size_t>(tile.width) * tile.height, 4);
  RayCache c(tile, imageWidth, counts, settingsFor(SampleFormat::Float));
  std::vector<RaySample> all;
  for (int y = tile.y0; y < tile.y0 + tile.height; ++y)
    for (int x = tile.x0; x < tile.x0 + tile.width; ++x) {
      RaySample s;
      s.pixel = static_cast<std::uint32_t>(y * imageWidth + x);
      s.k = 2;
      s.r = static_cast<float>(x) / 128.0f;
      s.g = static_cast<float>(y) / 128.0f;
      s.a = 1.0f;
      all.push_back(s);
    }
  c.put(all.data(), all.size());
  c.composite();
  for (int ty = 0; ty < tile.height; ++ty)
    for (int tx = 0; tx < tile.width; ++tx) {
      EXPECT_EQ(c.image().pixel(tx, ty)[0], static_cast<float>(tx + tile.x0) / 128.0f);
      EXPECT_EQ(c.image().pixel(tx, ty)[1], static_cast<float>(ty + tile.y0) / 128.0f);
      EXPECT_EQ(c.image().pixel(tx, ty)[3], 1.0f);
    }
  auto at = [&](int x, int y, std::uint32_t k = 0) { return sample(static_cast<std::uint32_t>(y * imageWidth + x), k, 0.1f); };
  for (const RaySample& bad : {at(tile.x0 - 1, tile.y0), at(tile.x0 + tile.width, tile.y0), at(tile.x0, tile.y0 - 1),
                               at(tile.x0, tile.y0 + tile.height), at(tile.x0 + 3, tile.y0 + 3, 4)})
    EXPECT_THROW(c.put(&bad, 1), pp5::InvariantError);
  EXPECT_NO_THROW({
    const RaySample ok = at(tile.x0 + tile.width - 1, tile.y0 + tile.height - 1, 3);
    c.put(&ok, 1);
  });
}

// Tiles of one image give the image that one whole-image cache gives.
TEST(Tiles, TilesAssembleToTheWholeImage) {
  const int w = 40, h = 30;
  std::vector<std::uint16_t> counts(static_cast<std::size_t>(w) * h);
  std::mt19937 rng(3);
  for (auto& c : counts) c = static_cast<std::uint16_t>(rng() % 120);
  std::uniform_real_distribution<float> a(0.0f, 0.1f);
  std::vector<RaySample> all;
  for (int i = 0; i < w * h; ++i)
    for (std::uint32_t k = 0; k < counts[i]; ++k) all.push_back(sample(static_cast<std::uint32_t>(i), k, a(rng)));
  RayCache whole(TileRect{0, 0, w, h}, w, counts, RayCacheSettings{});
  whole.put(all.data(), all.size());
  whole.composite();
  for (const TileRect t : {TileRect{0, 0, 16, 16}, TileRect{16, 0, 24, 16}, TileRect{0, 16, 16, 14}, TileRect{16, 16, 24, 14}}) {
    std::vector<std::uint16_t> tc;
    std::vector<RaySample> ts;
    for (int y = t.y0; y < t.y0 + t.height; ++y)
      for (int x = t.x0; x < t.x0 + t.width; ++x) tc.push_back(counts[y * w + x]);
    for (const RaySample& s : all) {
      const int x = static_cast<int>(s.pixel) % w, y = static_cast<int>(s.pixel) / w;
      if (x >= t.x0 && x < t.x0 + t.width && y >= t.y0 && y < t.y0 + t.height) ts.push_back(s);
    }
    RayCache c(t, w, tc, RayCacheSettings{});
    c.put(ts.data(), ts.size());
    c.composite();
    for (int y = 0; y < t.height; ++y)
      ASSERT_EQ(std::memcmp(c.image().pixel(0, y), whole.image().pixel(t.x0, t.y0 + y), 16 * t.width), 0);
  }
}

// Caches of disjoint tiles share nothing: used from two threads at once they
// give what they give one after the other.
TEST(Tiles, DisjointTilesFromTwoThreads) {
  const int w = 64, h = 32;
  std::vector<std::uint16_t> counts(static_cast<std::size_t>(w / 2) * h, 200);
  std::vector<RaySample> left, right;
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> a(0.0f, 0.05f);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (std::uint32_t k = 0; k < 200; ++k)
        (x < w / 2 ? left : right).push_back(sample(static_cast<std::uint32_t>(y * w + x), k, a(rng)));
  auto render = [&](const TileRect& t, const std::vector<RaySample>& smp, TileImage& out) {
    RayCache c(t, w, counts, RayCacheSettings{}, CompositeMode::Over, 2);
    for (std::size_t i = 0; i < smp.size(); i += 997) c.put(smp.data() + i, std::min<std::size_t>(997, smp.size() - i));
    c.composite();
    out = c.image();
  };
  const TileRect lt{0, 0, w / 2, h}, rt{w / 2, 0, w / 2, h};
  TileImage l1, r1, l2, r2;
  render(lt, left, l1);
  render(rt, right, r1);
  std::thread t1([&] { render(lt, left, l2); });
  std::thread t2([&] { render(rt, right, r2); });
  t1.join();
  t2.join();
  EXPECT_TRUE(sameBits(l1, l2));
  EXPECT_TRUE(sameBits(r1, r2));
}

// ---------------------------------------------------------------------------
// The storage format: error against float storage, in 8-bit display levels,
// for rays like a fine lattice's through speckle (the figures behind the
// default; docs/rendering.md).

struct FormatError {
  double maxLevels = 0, meanLevels = 0;
};

// Realistic rays: 512 samples each, a quarter of them empty (below the
// transfer function's threshold), the rest at a per-ray opacity level
// log-uniform in [0.002, 0.05] with +-50 % speckle, clamped to that range.
std::vector<RaySample> realisticRays(int nrays, int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<RaySample> v;
  v.reserve(static_cast<std::size_t>(nrays) * n);
  for (int i = 0; i < nrays; ++i) {
    const float level = 0.002f * std::pow(25.0f, u(rng));
    for (int k = 0; k < n; ++k) {
      const float a = u(rng) < 0.25f ? 0.0f : std::clamp(level * (0.5f + u(rng)), 0.002f, 0.05f);
      v.push_back(sample(static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(k), a, 0.3f + 0.7f * u(rng)));
    }
  }
  return v;
}

FormatError formatError(SampleFormat f, CompositeMode m, bool termination, const std::vector<RaySample>& rays,
                        int nrays, int n) {
  const std::vector<std::uint16_t> counts(nrays, static_cast<std::uint16_t>(n));
  const TileRect tile{0, 0, nrays, 1};
  RayCache ref(tile, nrays, counts, settingsFor(SampleFormat::Float, 32, termination), m, 0);
  RayCache c(tile, nrays, counts, settingsFor(f, 32, termination), m, 0);
  ref.put(rays.data(), rays.size());
  c.put(rays.data(), rays.size());
  ref.composite();
  c.composite();
  FormatError e;
  for (std::size_t i = 0; i < ref.image().rgba.size(); ++i) {
    const double d = std::abs(static_cast<double>(c.image().rgba[i]) - ref.image().rgba[i]) * 255.0;
    e.maxLevels = std::max(e.maxLevels, d);
    e.meanLevels += d;
  }
  e.meanLevels /= static_cast<double>(ref.image().rgba.size());
  return e;
}

TEST(FormatChoice, HalfIsWithinATenthOfALevelRgba8IsNot) {
  const int nrays = 2000, n = 512;
  const std::vector<RaySample> rays = realisticRays(nrays, n, 42);
  for (auto m : kModes)
    for (bool term : {true, false}) {
      if (m != CompositeMode::Over && term) continue;
      const FormatError half = formatError(SampleFormat::Half, m, term, rays, nrays, n);
      const FormatError rgba8 = formatError(SampleFormat::Rgba8, m, term, rays, nrays, n);
      std::printf("format error vs float, %s%s, 8-bit levels: half max %.4f mean %.5f; rgba8 max %.3f mean %.4f\n",
                  pp5::pp::compositeModeName(m), term ? " (terminated)" : "", half.maxLevels, half.meanLevels,
                  rgba8.maxLevels, rgba8.meanLevels);
      // The bound the default rests on: half is far below one display level.
      EXPECT_LT(half.maxLevels, 0.1);
      if (m == CompositeMode::Over) {
        EXPECT_GT(rgba8.maxLevels, 5.0) << "rgba8 would do: reconsider the default";
      }
    }
  EXPECT_EQ(RayCacheSettings{}.format, SampleFormat::Half);
}

// ---------------------------------------------------------------------------
// Options and output.

TEST(Options, RegisteredWithDefaultsAndRanges) {
  pp5::ConfigSchema schema;
  RayCacheSettings s;
  s.blockSize = 3;
  pp5::pp::registerOptions(schema, s);
  EXPECT_EQ(s.blockSize, 32);
  EXPECT_EQ(s.format, SampleFormat::Half);
  EXPECT_TRUE(s.earlyTermination);
  EXPECT_DOUBLE_EQ(s.terminationAlpha, 1.0 - 1.0 / 512.0);
  for (const auto& e : schema.entries()) EXPECT_FALSE(e.doc.empty()) << e.key;
  schema.loadString("[render.cache]\nblock_size = 16\nformat = \"float\"\nadditive_scale = 0.5\n", "cfg.toml");
  EXPECT_EQ(s.blockSize, 16);
  EXPECT_EQ(s.format, SampleFormat::Float);
  EXPECT_NO_THROW(s.validate());
  EXPECT_THROW(schema.loadString("[render.cache]\nformat = \"int8\"\n", "cfg.toml"), pp5::InputError);
  EXPECT_THROW(schema.loadString("[render.cache]\ntermination_alpha = 0.2\n", "cfg.toml"), pp5::InputError);
  schema.loadString("[render.cache]\nblock_size = 24\n", "cfg.toml");
  EXPECT_THROW(s.validate(), pp5::InputError);
  EXPECT_THROW(RayCache(TileRect{0, 0, 1, 1}, 1, std::vector<std::uint16_t>{1}, s), pp5::InputError);
  EXPECT_EQ(pp5::pp::compositeModeFromName("additive"), CompositeMode::Additive);
  EXPECT_THROW(pp5::pp::compositeModeFromName("sum"), pp5::InputError);
}

TEST(Output, EightBitOverBackgroundAndStraightAlpha) {
  TileImage im;
  im.width = 2;
  im.height = 1;
  im.rgba = {0.25f, 0.5f, 0.0f, 0.5f, 0.0f, 0.0f, 0.0f, 0.0f};
  const float bg[3] = {1.0f, 0.0f, 0.2f};
  std::uint8_t rgb[6], rgba[8];
  pp5::pp::toRgb8(im, bg, rgb);
  EXPECT_EQ(rgb[0], 191);  // 0.25 + 0.5 * 1
  EXPECT_EQ(rgb[1], 128);
  EXPECT_EQ(rgb[2], 26);  // 0.5 * 0.2
  EXPECT_EQ(rgb[3], 255);
  EXPECT_EQ(rgb[5], 51);
  pp5::pp::toRgba8(im, rgba);
  EXPECT_EQ(rgba[0], 128);
  EXPECT_EQ(rgba[1], 255);
  EXPECT_EQ(rgba[3], 128);
  EXPECT_EQ(rgba[7], 0);
}

// Neighbouring rays share their storage by depth (RayCache::Ray::at). Each
// ray must still hold its own samples: every ray of a tile with uneven
// counts (some empty, a strided row and column of them, groups cut short at
// the tile's edges) composites to what the same samples give in a cache of
// that one pixel, where the layout is a plain run.
TEST(Layout, EveryRayKeepsItsOwnSamples) {
  const TileRect tile{3, 2, 21, 13};
  const int imageWidth = 30;
  std::mt19937 rng(56);
  const std::size_t n = static_cast<std::size_t>(tile.width) * tile.height;
  std::vector<std::uint16_t> counts(n);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t x = i % tile.width, y = i / tile.width;
    // Columns 5 and 11 and row 7 hold no rays, as a strided view's do.
    counts[i] = (x == 5 || x == 11 || y == 7 || rng() % 7 == 0) ? 0 : static_cast<std::uint16_t>(1 + rng() % 300);
  }
  std::uniform_real_distribution<float> a(0.0f, 0.08f);
  for (auto f : kFormats)
    for (int bs : {1, 8, 32, 256}) {
      const RayCacheSettings s = settingsFor(f, bs, false);
      RayCache cache(tile, imageWidth, counts, s, CompositeMode::Over);
      std::vector<std::vector<RaySample>> own(n);
      std::vector<RaySample> all;
      for (std::size_t i = 0; i < n; ++i) {
        const auto pixel = static_cast<std::uint32_t>((tile.y0 + i / tile.width) * imageWidth + tile.x0 + i % tile.width);
        for (std::uint32_t k = 0; k < counts[i]; ++k) own[i].push_back(sample(pixel, k, a(rng), 0.3f + 0.001f * k));
        all.insert(all.end(), own[i].begin(), own[i].end());
      }
      std::shuffle(all.begin(), all.end(), rng);
      cache.put(all);
      cache.composite();
      for (std::size_t i = 0; i < n; ++i) {
        const int x = tile.x0 + static_cast<int>(i % tile.width), y = tile.y0 + static_cast<int>(i / tile.width);
        const std::uint16_t one[1] = {counts[i]};
        RayCache alone(TileRect{x, y, 1, 1}, imageWidth, one, s, CompositeMode::Over);
        alone.put(own[i]);
        alone.composite();
        ASSERT_EQ(std::memcmp(alone.image().pixel(0, 0), cache.image().pixel(x - tile.x0, y - tile.y0), 4 * sizeof(float)), 0)
            << pp5::pp::sampleFormatName(f) << " block " << bs << " ray " << i;
      }
    }
}

// What the layout is for: a surface that comes into view behind 8 x 8
// neighbouring pixels at one depth writes a few fresh pages of memory, where
// a ray after ray layout wrote one a ray (each fresh page is zeroed by the
// kernel at its first write: a minor page fault).
TEST(Layout, NeighbouringRaysShareFreshPages) {
  const TileRect tile{0, 0, 64, 64};
  const std::vector<std::uint16_t> counts(64 * 64, 512);  // 4 KiB of half samples a ray
  RayCache cache(tile, 64, counts, settingsFor(SampleFormat::Half), CompositeMode::Over);
  std::vector<RaySample> surface;
  for (std::uint32_t y = 16; y < 24; ++y)
    for (std::uint32_t x = 16; x < 24; ++x) surface.push_back(sample(y * 64 + x, 300 + (x + y) % 3, 0.5f));
  surface.reserve(surface.size() + 1);
  rusage before{}, after{};
  getrusage(RUSAGE_SELF, &before);
  cache.put(surface);
  getrusage(RUSAGE_SELF, &after);
  // 64 rays in 4 groups of 4 x 4: 4 pages, and the dirty-ray list's growth.
  EXPECT_LE(after.ru_minflt - before.ru_minflt, 12) << "fresh pages for 64 neighbouring rays";
}

TEST(Memory, CountsSamplesPartialsAndFlags) {
  const std::vector<std::uint16_t> counts(100, 64);
  for (auto f : kFormats) {
    RayCache c(TileRect{0, 0, 10, 10}, 10, counts, settingsFor(f, 16));
    EXPECT_EQ(c.sampleCount(), 6400u);
    EXPECT_EQ(c.blockCount(), 400u);
    // Samples, partials and dirty flags, the image, and a touched flag per 64 samples.
    const std::size_t floor = 6400 * pp5::pp::sampleFormatBytes(f) + 400 * (16 + 1) + 100 * 16 + 6400 / 64;
    EXPECT_GE(c.memoryBytes(), floor);
    EXPECT_LE(c.memoryBytes(), floor + 100 * 32);
  }
}

}  // namespace
