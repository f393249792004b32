// The resolution cell measured from the differences of consecutive frames
// (analysis/speckle_cell.hpp): against speckle of a known correlation, and against
// the simulator's beams.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "core/error.hpp"
#include "analysis/speckle_cell.hpp"
#include "sim/bmode.hpp"
#include "sim/simulate.hpp"

namespace {

using namespace pp5;
using namespace pp5::gp;

constexpr int kW = 256, kH = 256;

// White noise filtered by a Gaussian of sigmas (sx, sy) pixels, unit variance.
// Its autocorrelation is exp(-d^2 / (4 sigma^2)) along each axis, whose half
// width at half maximum is 2 sigma sqrt(ln 2).
std::vector<double> speckle(double sx, double sy, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  std::vector<double> white(static_cast<std::size_t>(kW) * kH), tmp(white.size(), 0.0), out(white.size(), 0.0);
  for (double& v : white) v = n01(rng);
  auto taps = [](double s) {
    const int r = static_cast<int>(std::ceil(4.0 * s));
    std::vector<double> t(2 * r + 1);
    for (int i = -r; i <= r; ++i) t[i + r] = std::exp(-0.5 * i * i / (s * s));
    return t;
  };
  const std::vector<double> tx = taps(sx), ty = taps(sy);
  const int rx = static_cast<int>(tx.size() / 2), ry = static_cast<int>(ty.size() / 2);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x)
      for (int i = -rx; i <= rx; ++i) tmp[y * kW + x] += tx[i + rx] * white[y * kW + (x + i + kW) % kW];
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x)
      for (int j = -ry; j <= ry; ++j) out[y * kW + x] += ty[j + ry] * tmp[((y + j + kH) % kH) * kW + x];
  double var = 0.0;
  for (const double v : out) var += v * v;
  var /= static_cast<double>(out.size());
  for (double& v : out) v /= std::sqrt(var);
  return out;
}

// A frame: anatomy (bright where `anatomy` says) plus 20 grey levels of speckle.
Frame frame(const std::vector<double>& anatomy, const std::vector<double>& noise, std::uint64_t index) {
  Frame f;
  f.allocate(kW, kH, PixelType::U8);
  f.index = index;
  for (std::size_t i = 0; i < f.pixels.size(); ++i)
    f.pixels[i] = static_cast<std::uint8_t>(std::clamp(std::lround(anatomy[i] + 20.0 * noise[i]), 1L, 255L));
  return f;
}

// Anatomy both frames share: a mid-grey background, a bright slab with a
// sharp edge, and a bright disc.
std::vector<double> anatomy() {
  std::vector<double> a(static_cast<std::size_t>(kW) * kH, 90.0);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      if (y > 150 && y < 190) a[y * kW + x] = 170.0;
      if (std::hypot(x - 80.0, y - 70.0) < 30.0) a[y * kW + x] = 150.0;
    }
  return a;
}

std::vector<PixelRun> wholeFrame() {
  std::vector<PixelRun> runs;
  for (int y = 0; y < kH; ++y) runs.push_back({y, 0, kW - 1});
  return runs;
}

SpeckleCell measure(double sx, double sy, const std::vector<double>& shared, int pairs = 3) {
  SpeckleCellMeter meter;
  for (int p = 0; p < pairs; ++p) {
    const Frame a = frame(shared, speckle(sx, sy, 11u + 2u * p), 2u * p);
    const Frame b = frame(shared, speckle(sx, sy, 12u + 2u * p), 2u * p + 1);
    EXPECT_TRUE(meter.add(a, b, wholeFrame()));
  }
  return meter.result();
}

TEST(SpeckleCell, HalfWidthsOfSpeckleOfAKnownCorrelation) {
  const double sx = 3.0, sy = 1.5;
  const SpeckleCell c = measure(sx, sy, anatomy());
  EXPECT_EQ(c.pairs, 3u);
  ASSERT_TRUE(c.lateralPx && c.axialPx);
  const double k = 2.0 * std::sqrt(std::log(2.0));
  EXPECT_NEAR(*c.lateralPx, k * sx, 0.07 * k * sx);
  EXPECT_NEAR(*c.axialPx, k * sy, 0.07 * k * sy);
  ASSERT_GE(c.lateral.size(), 10u);
  EXPECT_DOUBLE_EQ(c.lateral[0], 1.0);
  EXPECT_DOUBLE_EQ(c.axial[0], 1.0);
}

TEST(SpeckleCell, TheAnatomyTheFramesShareCancels) {
  // The same speckle over a flat background and over sharp-edged anatomy:
  // the same cell. A single frame's own autocorrelation would see the slab.
  const SpeckleCell flat = measure(2.0, 2.0, std::vector<double>(static_cast<std::size_t>(kW) * kH, 120.0));
  const SpeckleCell busy = measure(2.0, 2.0, anatomy());
  ASSERT_TRUE(flat.lateralPx && busy.lateralPx && flat.axialPx && busy.axialPx);
  EXPECT_NEAR(*busy.lateralPx, *flat.lateralPx, 0.05 * *flat.lateralPx);
  EXPECT_NEAR(*busy.axialPx, *flat.axialPx, 0.05 * *flat.axialPx);
}

TEST(SpeckleCell, WhiteNoiseIsNotSpeckleAndIdenticalFramesGiveNothing) {
  // White noise alone: no block is taken, no pair counts.
  SpeckleCellMeter noise;
  EXPECT_FALSE(noise.add(frame(anatomy(), speckle(0.2, 0.2, 1u), 0), frame(anatomy(), speckle(0.2, 0.2, 2u), 1),
                         wholeFrame()));
  EXPECT_EQ(noise.result().pairs, 0u);
  EXPECT_FALSE(noise.result().lateralPx);

  // Speckle in the top half, white noise in the bottom half (a water bath):
  // the speckle's cell, as if the noise were not there.
  auto halfAndHalf = [](unsigned seed) {
    std::vector<double> v = speckle(2.5, 1.5, seed);
    const std::vector<double> white = speckle(0.2, 0.2, seed + 100u);
    std::copy(white.begin() + kW * kH / 2, white.end(), v.begin() + kW * kH / 2);
    return v;
  };
  SpeckleCellMeter mixed;
  for (unsigned p = 0; p < 3; ++p)
    EXPECT_TRUE(mixed.add(frame(anatomy(), halfAndHalf(21u + 2u * p), 0), frame(anatomy(), halfAndHalf(22u + 2u * p), 1),
                          wholeFrame()));
  const SpeckleCell c = mixed.result();
  const double k = 2.0 * std::sqrt(std::log(2.0));
  ASSERT_TRUE(c.lateralPx && c.axialPx);
  EXPECT_NEAR(*c.lateralPx, k * 2.5, 0.07 * k * 2.5);
  EXPECT_NEAR(*c.axialPx, k * 1.5, 0.07 * k * 1.5);
  EXPECT_LT(c.pixels, 3u * kW * kH * 6u / 10u);  // about half of each pair's pixels

  // Two identical frames: a difference of nothing.
  SpeckleCellMeter meter;
  const Frame a = frame(anatomy(), speckle(2.0, 2.0, 5u), 0);
  EXPECT_FALSE(meter.add(a, a, wholeFrame()));
  const SpeckleCell same = meter.result();
  EXPECT_FALSE(same.lateralPx);
  EXPECT_FALSE(same.axialPx);
  EXPECT_TRUE(same.lateral.empty());
}

TEST(SpeckleCell, AWideCellIsReportedAsWiderThanTheLargestLag) {
  SpeckleCellMeter meter(4);
  const std::vector<double> flat(static_cast<std::size_t>(kW) * kH, 120.0);
  EXPECT_TRUE(meter.add(frame(flat, speckle(6.0, 1.0, 1u), 0), frame(flat, speckle(6.0, 1.0, 2u), 1), wholeFrame()));
  const SpeckleCell c = meter.result();
  EXPECT_FALSE(c.lateralPx);  // about 10 px: past lag 4
  ASSERT_TRUE(c.axialPx);
  EXPECT_EQ(c.lateral.size(), 5u);
}

TEST(SpeckleCell, RefusesFramesOfAnotherSizeAndSkipsDarkPairs) {
  SpeckleCellMeter meter;
  Frame small;
  small.allocate(64, 64, PixelType::U8);
  const Frame a = frame(anatomy(), speckle(2.0, 2.0, 3u), 0);
  EXPECT_THROW(meter.add(a, small, wholeFrame()), InputError);
  Frame dark;
  dark.allocate(kW, kH, PixelType::U8);  // all zero: nothing inside to measure
  EXPECT_FALSE(meter.add(dark, dark, wholeFrame()));
  EXPECT_EQ(meter.result().pairs, 0u);
  EXPECT_EQ(meter.result().elevation, SpeckleCell::Elevation::NoTriple);
  EXPECT_TRUE(meter.add(a, frame(anatomy(), speckle(2.0, 2.0, 4u), 1), wholeFrame()));
  Frame other;
  other.allocate(128, 128, PixelType::U8);
  EXPECT_THROW(meter.add(other, other, {}), InputError);  // a size other than the first pair's
}

TEST(SpeckleCell, KernelScaledFromTheCellAndTheSpacing) {
  SpeckleCell c;
  c.lateralPx = 3.0;
  c.axialPx = 0.6;  // under a pixel: the pixel's
  const auto k = kernelFromCell(c, 0.4, 0.5, 2.0);
  ASSERT_TRUE(k);
  EXPECT_DOUBLE_EQ(k->lateralMm, kKernelPerLateralCell * 3.0 * 0.4);
  EXPECT_DOUBLE_EQ(k->axialMm, kKernelPerAxialCell * 1.0 * 0.5);
  EXPECT_DOUBLE_EQ(k->elevationMm, kKernelPerFrameSpacing * 2.0);
  // Pixels subsampled to 1.0 x 2.0 mm before the reconstruction: a cell under them counts as them.
  const auto sub = kernelFromCell(c, 0.4, 0.5, 2.0, 1.0, 2.0);
  ASSERT_TRUE(sub);
  EXPECT_DOUBLE_EQ(sub->lateralMm, kKernelPerLateralCell * 3.0 * 0.4);  // 1.2 mm of cell is over 1 mm
  EXPECT_DOUBLE_EQ(sub->axialMm, kKernelPerAxialCell * 2.0);
  EXPECT_DOUBLE_EQ(sub->elevationMm, k->elevationMm);
  c.axialPx.reset();  // not measured: no suggestion
  EXPECT_FALSE(kernelFromCell(c, 0.4, 0.5, 2.0));
}

// Frames as slices 1 mm apart through white noise filtered by a Gaussian of
// sigmas (2, 1.5) pixels in plane and sz slices along the sweep: the speckle's
// correlation between slices d apart is exp(-d^2 / (4 sz^2)), whose half width
// at half maximum is 2 sz sqrt(ln 2) mm.
std::vector<Frame> sweepThroughSpeckle(double sz, int slices, unsigned seed) {
  const int n = kW * kH;
  std::mt19937 rng(seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  std::vector<double> v(static_cast<std::size_t>(n) * slices);
  for (double& x : v) x = n01(rng);
  auto blur = [&](int stride, int count, int len, double sigma) {  // along one axis, wrapping around
    const int r = static_cast<int>(std::ceil(4.0 * sigma));
    std::vector<double> taps(2 * r + 1), line(len);
    for (int i = -r; i <= r; ++i) taps[i + r] = std::exp(-0.5 * i * i / (sigma * sigma));
    for (int base = 0; base < count; ++base) {
      const std::size_t start = stride == 1 ? static_cast<std::size_t>(base) * len
                                            : (stride == kW ? static_cast<std::size_t>(base / kW) * n + base % kW
                                                            : static_cast<std::size_t>(base));
      for (int j = 0; j < len; ++j) {
        double acc = 0.0;
        for (int i = -r; i <= r; ++i) acc += taps[i + r] * v[start + static_cast<std::size_t>((j + i + len) % len) * stride];
        line[j] = acc;
      }
      for (int j = 0; j < len; ++j) v[start + static_cast<std::size_t>(j) * stride] = line[j];
    }
  };
  blur(1, kH * slices, kW, 2.0);      // rows
  blur(kW, kW * slices, kH, 1.5);     // columns, in every slice
  blur(n, n, slices, sz);             // along the sweep
  double var = 0.0;
  for (const double x : v) var += x * x;
  const double sd = std::sqrt(var / static_cast<double>(v.size()));
  std::vector<Frame> frames;
  const std::vector<double> a = anatomy();
  for (int z = 0; z < slices; ++z) {
    std::vector<double> noise(v.begin() + static_cast<std::ptrdiff_t>(z) * n, v.begin() + static_cast<std::ptrdiff_t>(z + 1) * n);
    for (double& x : noise) x /= sd;
    frames.push_back(frame(a, noise, static_cast<std::uint64_t>(z)));
  }
  return frames;
}

TEST(SpeckleCell, ElevationHalfWidthOfSpeckleOfAKnownCorrelation) {
  for (const double sz : {0.8, 1.2}) {
    // 16 slices, so that wrapping around joins slices far enough apart not to matter.
    const std::vector<Frame> f = sweepThroughSpeckle(sz, 16, 7u);
    SpeckleCellMeter meter;
    for (int i = 0; i + 2 < 8; ++i) EXPECT_TRUE(meter.addTriple(f[i], f[i + 1], f[i + 2], 1.0, 2.0, wholeFrame()));
    const SpeckleCell c = meter.result();
    EXPECT_EQ(c.triples, 6u);
    EXPECT_DOUBLE_EQ(c.nearMm, 1.0);
    EXPECT_DOUBLE_EQ(c.farMm, 2.0);
    ASSERT_TRUE(c.elevationMm) << "sz " << sz << ", variance ratio " << c.varianceRatio;
    EXPECT_EQ(c.elevation, SpeckleCell::Elevation::Measured);
    const double want = 2.0 * sz * std::sqrt(std::log(2.0));
    EXPECT_NEAR(*c.elevationMm, want, 0.1 * want) << "sz " << sz;
  }
  // Decorrelated frames (independent speckle in each): nothing to read.
  SpeckleCellMeter apart;
  const std::vector<double> a = anatomy();
  EXPECT_TRUE(apart.addTriple(frame(a, speckle(2.0, 1.5, 1u), 0), frame(a, speckle(2.0, 1.5, 2u), 1),
                              frame(a, speckle(2.0, 1.5, 3u), 2), 1.0, 2.0, wholeFrame()));
  const SpeckleCell c = apart.result();
  EXPECT_EQ(c.triples, 1u);
  EXPECT_NEAR(c.varianceRatio, 1.0, 0.1);
  EXPECT_FALSE(c.elevationMm);
  EXPECT_EQ(c.elevation, SpeckleCell::Elevation::Decorrelated);
  // Not three frames in a row: refused without counting.
  EXPECT_FALSE(apart.addTriple(frame(a, speckle(2.0, 1.5, 1u), 0), frame(a, speckle(2.0, 1.5, 2u), 1),
                               frame(a, speckle(2.0, 1.5, 3u), 2), 1.0, 1.0, wholeFrame()));
  EXPECT_EQ(apart.result().triples, 1u);
}

// The simulator's beams: the speckle's half width (about 1.18 sigma of the
// two-way amplitude beam, sigma = FWHM / 2.355) lies between the focus's and
// the widest, at the image's far end.
TEST(SpeckleCell, FollowsTheSimulatorsBeams) {
  for (const char* preset : {"paper35", "linear75"}) {
    sim::SimSettings ss;
    const bool forearm = std::string(preset) == "linear75";
    ss.phantom = forearm ? sim::PhantomKind::Forearm : sim::PhantomKind::Doll;
    ss.probe.preset = forearm ? sim::ProbePreset::Linear75 : sim::ProbePreset::Paper35;
    ss.bmode.medium = sim::Medium::Ideal;
    ss.sweep.captureIntervalMm = 2.0;
    ss.sweep.maxFrames = 5;
    ss.threads = 2;
    const sim::SweepSimulator simulator(ss);
    const sim::ProbeModel& probe = simulator.probe();
    std::vector<PixelRun> runs;
    for (int y = 0; y < probe.height; ++y) runs.push_back({y, 0, probe.width - 1});
    SpeckleCellMeter meter;
    Frame prev = simulator.frame(0);
    for (std::size_t i = 1; i < simulator.frameCount(); ++i) {
      Frame cur = simulator.frame(i);
      meter.add(prev, cur, runs);
      prev = std::move(cur);
    }
    const SpeckleCell c = meter.result();
    ASSERT_TRUE(c.lateralPx) << preset;
    const double mm = *c.lateralPx * probe.spacingX();
    const double k = std::sqrt(2.0 * std::log(2.0));
    const double nearest = k * probe.lateralSigmaMm(probe.lateralFocusMm);
    const double widest = k * std::max(probe.lateralSigmaMm(0.0), probe.lateralSigmaMm(probe.depthMm));
    EXPECT_GT(mm, 0.9 * nearest) << preset;
    EXPECT_LT(mm, widest) << preset;
  }
}

}  // namespace
