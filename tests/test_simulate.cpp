// A whole simulated acquisition: the frames agree with the phantom where the
// recorded poses say they were taken, the truth volume agrees with the frames,
// and `pp5echo simulate` writes readable PLUS data.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <numeric>
#include <sstream>

#include "cli_test_util.hpp"
#include "core/error.hpp"
#include "formats/image_io.hpp"
#include "formats/plus_config.hpp"
#include "formats/sequence_io.hpp"
#include "formats/volume_io.hpp"
#include "sim/simulate.hpp"

namespace fs = std::filesystem;
using namespace pp5;
using namespace pp5::sim;

namespace {

// The brightest pixel in rows [r0, r1) and its intensity-weighted centroid
// over a 5 x 5 window (pixels within 30 of the peak).
struct Spot {
  double col = 0, row = 0, peak = 0;
};
Spot brightestSpot(const Frame& f, int r0, int r1, int c0 = 0, int c1 = -1) {
  if (c1 < 0) c1 = f.width;
  int bc = c0, br = r0;
  for (int r = r0; r < r1; ++r)
    for (int c = c0; c < c1; ++c)
      if (f.value(c, r) > f.value(bc, br)) {
        bc = c;
        br = r;
      }
  Spot s;
  s.peak = f.value(bc, br);
  double w = 0;
  for (int r = std::max(0, br - 2); r <= std::min(f.height - 1, br + 2); ++r)
    for (int c = std::max(0, bc - 2); c <= std::min(f.width - 1, bc + 2); ++c) {
      const double v = f.value(c, r) - (s.peak - 30.0);
      if (v <= 0) continue;
      s.col += v * c;
      s.row += v * r;
      w += v;
    }
  s.col /= w;
  s.row /= w;
  return s;
}

// True when the tissue is the same everywhere within `radius` mm of p in the
// image plane (and within half that in elevation): beyond the PSF's reach.
bool uniformAround(const Phantom& ph, const Mat4& imageToRef, const Vec3& pixel, double radius) {
  const Vec3 p = transformPoint(imageToRef, pixel);
  const Tissue t = ph.tissueAt(p);
  const Vec3 u = glm::normalize(transformVector(imageToRef, {1, 0, 0}));
  const Vec3 v = glm::normalize(transformVector(imageToRef, {0, 1, 0}));
  const Vec3 n = glm::cross(u, v);
  for (const Wire& w : ph.wires)  // too thin for the samples below to catch
    if (sdf::capsule(p, w.a, w.b, w.radius) < radius) return false;
  for (double r : {0.5 * radius, radius})
    for (int k = 0; k < 12; ++k) {
      const double a = k * std::numbers::pi / 6.0;
      if (ph.tissueAt(p + r * (std::cos(a) * u + std::sin(a) * v)) != t) return false;
    }
  return ph.tissueAt(p + 0.5 * radius * n) == t && ph.tissueAt(p - 0.5 * radius * n) == t;
}

double localMean(const Frame& f, int c, int r, int half) {
  double sum = 0;
  int n = 0;
  for (int rr = std::max(0, r - half); rr <= std::min(f.height - 1, r + half); ++rr)
    for (int cc = std::max(0, c - half); cc <= std::min(f.width - 1, c + half); ++cc) {
      sum += f.value(cc, rr);
      ++n;
    }
  return sum / n;
}

SimSettings settingsFor(const std::string& phantom) {
  SimSettings s;
  s.phantom = pp5::enumFromName<pp5::sim::PhantomKind>(phantom);
  s.threads = 1;
  return s;
}

std::string runBinary(const std::string& args, int* status) {
  const pp5::test::CliResult r = pp5::test::runCli(args);
  *status = r.status;
  return r.out;
}

fs::path freshDir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("pp5_test_simulate_" + name + "_" + std::to_string(getpid()));
  fs::remove_all(d);
  return d;
}

}  // namespace

TEST(Simulate, FramesCarryPosesAndArmReadings) {
  const SweepSimulator sim(settingsFor("doll"));
  ASSERT_GT(sim.frameCount(), 80u);
  ASSERT_LT(sim.frameCount(), 100u);
  const Frame f = sim.frame(3);
  EXPECT_EQ(f.width, 256);
  EXPECT_EQ(f.height, 405);
  EXPECT_EQ(f.pixelType, PixelType::U8);
  EXPECT_EQ(f.index, 3u);
  EXPECT_DOUBLE_EQ(f.timestamp, sim.sweep().frames[3].timestamp);
  const FrameTransform* p2t = f.findTransform("ProbeToTracker");
  const FrameTransform* r2t = f.findTransform("ReferenceToTracker");
  ASSERT_TRUE(p2t && r2t && f.findTransform("TrueProbeToTracker"));
  EXPECT_TRUE(p2t->valid);
  // ImageToReference = inv(ReferenceToTracker) * ProbeToTracker * ImageToProbe.
  const CalibrationChain chain{sim.imageToProbe(), p2t->matrix, r2t->matrix};
  const Mat4 m = chain.imageToReference();
  const Mat4 expected = sim.imageToReference(3);
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r) EXPECT_NEAR(m[c][r], expected[c][r], 1e-9);
  const std::string* counts = f.findField("ArmCounts");
  ASSERT_TRUE(counts);
  std::istringstream in(*counts);
  int x = -1, y = -1, t = -1;
  in >> x >> y >> t;
  ASSERT_FALSE(in.fail());
  for (int c : {x, y, t}) {
    EXPECT_GE(c, 0);
    EXPECT_LE(c, 4095);
  }
  EXPECT_TRUE(f.findField("ArmPosition"));
}

// Point targets locate the image exactly: the suspension wire (a dot) and the
// tank bottom (a line), projected through each frame's recorded pose, land
// where the phantom has them.
TEST(Simulate, WireAndTankBottomProjectToWhereThePhantomHasThem) {
  const SweepSimulator sim(settingsFor("doll"));
  const std::size_t n = sim.frameCount();
  for (std::size_t i : {std::size_t{0}, n / 4, n / 2, 3 * n / 4, n - 1}) {
    const Frame f = sim.frame(i);
    const Mat4 toRef = sim.imageToReference(i);
    // The wire runs along x at y = 0, z = 150: 30 mm below the probe.
    const Spot w = brightestSpot(f, 40, 85);
    EXPECT_GT(w.peak, 170.0) << "frame " << i;
    const Vec3 pw = transformPoint(toRef, {w.col, w.row, 0});
    EXPECT_NEAR(pw.y, 0.0, 0.6) << "frame " << i;
    EXPECT_NEAR(pw.z, 150.0, 0.6) << "frame " << i;
    // The bottom (z = 0) is the brightest row of columns clear of the doll's
    // shadow; average the depth of each column's peak.
    double zSum = 0;
    int cols = 0;
    for (int c = 0; c < f.width; c += 8) {
      const Spot b = brightestSpot(f, 355, 395, c, c + 1);
      if (b.peak < 200.0) continue;  // shadowed by the doll
      zSum += transformPoint(toRef, {b.col, b.row, 0}).z;
      ++cols;
    }
    ASSERT_GT(cols, 10) << "frame " << i;
    EXPECT_NEAR(zSum / cols, 0.0, 0.5) << "frame " << i;
  }
}

// The N-wire principle: where the diagonal wire crosses the image tells how far
// along x the image is, so this checks the elevation axis of the poses too.
TEST(Simulate, NWireGivesTheImagePositionAlongTheSweep) {
  const SweepSimulator sim(settingsFor("wires"));
  const std::size_t n = sim.frameCount();
  ASSERT_GT(n, 30u);
  for (std::size_t i = n / 6; i <= 5 * n / 6; i += n / 6) {  // where the diagonal is clear of the others
    const Frame f = sim.frame(i);
    const Mat4 toRef = sim.imageToReference(i);
    // Top layer, 30 mm deep: wires at y = -15 and +15 and the diagonal
    // y = 0.3 x between them.
    const Vec3 left = transformPoint(affineInverse(toRef), {0, 15.0, 90.0});  // (column, row) of y = +15
    const Vec3 right = transformPoint(affineInverse(toRef), {0, -15.0, 90.0});
    const int r0 = static_cast<int>(left.y) - 6, r1 = static_cast<int>(left.y) + 7;
    const int c0 = static_cast<int>(std::min(left.x, right.x)) + 8, c1 = static_cast<int>(std::max(left.x, right.x)) - 8;
    const Spot mid = brightestSpot(f, r0, r1, c0, c1);
    ASSERT_GT(mid.peak, 150.0) << "frame " << i;
    const Vec3 p = transformPoint(toRef, {mid.col, mid.row, 0});
    const double xFromWire = p.y / 0.3;
    const double xOfImage = transformPoint(toRef, {mid.col, mid.row, 0}).x;
    EXPECT_NEAR(xFromWire, xOfImage, 1.5) << "frame " << i;
  }
}

// Pixels projected through the recorded poses: water is dark and tissue
// well inside (beyond the PSF) is bright, and the truth volume sampled there
// agrees with the frame's neighbourhood.
TEST(Simulate, FramesAgreeWithThePhantomAndTheTruthVolume) {
  for (const std::string name : {"forearm", "doll"}) {
    const SweepSimulator sim(settingsFor(name));
    const Phantom& ph = sim.phantom();
    const std::size_t n = sim.frameCount();
    std::vector<Mat4> poses;
    for (std::size_t i = 0; i < n; ++i) poses.push_back(sim.imageToReference(i));
    // 2 mm voxels: a voxel's centre and sub-samples stay within the 3 mm of
    // uniform tissue around each point tested.
    Grid g = fitGrid(poses, sim.probe().width, sim.probe().height, Vec3(2.0), 2.0);
    const Volume truth = truthVolume(ph, sim.bmode(), g, ScalarType::F32, 1);
    std::vector<double> waterMeans, tissueMeans, truthErrors;
    for (std::size_t i = n / 5; i < n; i += n / 5) {
      const Frame f = sim.frame(i);
      const Mat4 toRef = poses[i];
      for (int c = 4; c < f.width - 4; c += 3) {
        bool shadowed = false;   // a strong reflector above, along the beam
        double attenuation = 0;  // dB of attenuation the TGC left uncompensated
        const double dy = sim.probe().spacingY(), f0 = sim.probe().centerMHz;
        for (int r = 0; r < f.height - 4; ++r) {
          const Vec3 p = transformPoint(toRef, {double(c), double(r), 0});
          const Phantom::Sample s = ph.sample(p);
          if (s.tissue == Tissue::Bone || s.tissue == Tissue::Glass || s.tissue == Tissue::HardPlastic) shadowed = true;
          const double depth = r * dy;
          const double tgc = depth > ph.scan.tgcStartMm && depth < ph.scan.tgcEndMm ? ph.scan.tgcDbPerCmMHz : 0.0;
          attenuation += 2.0 * (tissueProperties(s.tissue).attenuationDbPerCmMHz - tgc) * f0 * dy / 10.0;
          if (r < 4 || shadowed || !uniformAround(ph, toRef, {double(c), double(r), 0}, 3.0)) continue;
          const double m = localMean(f, c, r, 2);
          if (s.tissue == Tissue::Water) {
            waterMeans.push_back(m);
            continue;
          }
          if (std::abs(attenuation) > 8.0) continue;
          tissueMeans.push_back(m);
          const Vec3 v = g.worldToVoxel(p);
          const auto vi = static_cast<std::int64_t>(std::lround(v.x)), vj = static_cast<std::int64_t>(std::lround(v.y)),
                     vk = static_cast<std::int64_t>(std::lround(v.z));
          ASSERT_TRUE(g.contains(vi, vj, vk));
          // The truth leaves out attenuation; take off what the TGC did not make up.
          const double expected = truth.value(g.linear(vi, vj, vk)) - attenuation * 255.0 / 60.0;
          truthErrors.push_back(localMean(f, c, r, 3) - expected);
        }
      }
    }
    ASSERT_GT(waterMeans.size(), 1000u) << name;
    ASSERT_GT(tissueMeans.size(), 100u) << name;
    std::printf("%s: %zu water points (mean %.1f), %zu tissue points (mean %.1f), truth error mean %.2f\n",
                name.c_str(), waterMeans.size(), std::accumulate(waterMeans.begin(), waterMeans.end(), 0.0) / waterMeans.size(),
                tissueMeans.size(), std::accumulate(tissueMeans.begin(), tissueMeans.end(), 0.0) / tissueMeans.size(),
                std::accumulate(truthErrors.begin(), truthErrors.end(), 0.0) / truthErrors.size());
    const auto mean = [](const std::vector<double>& v) { return std::accumulate(v.begin(), v.end(), 0.0) / v.size(); };
    const double worstWater = *std::max_element(waterMeans.begin(), waterMeans.end());
    const double dimmestTissue = *std::min_element(tissueMeans.begin(), tissueMeans.end());
    EXPECT_LT(mean(waterMeans), 20.0) << name;
    EXPECT_LT(worstWater, 45.0) << name;
    EXPECT_GT(mean(tissueMeans), 50.0) << name;
    EXPECT_GT(dimmestTissue, worstWater) << name;
    // Truth vs frame: unbiased, and close at each point.
    double absSum = 0;
    for (double e : truthErrors) absSum += std::abs(e);
    EXPECT_NEAR(mean(truthErrors), 0.0, 5.0) << name;
    EXPECT_LT(absSum / truthErrors.size(), 12.0) << name;
  }
}

TEST(Simulate, TruthVolumeHoldsTheTissuesDisplayLevels) {
  const SweepSimulator sim(settingsFor("doll"));
  const Phantom& ph = sim.phantom();
  const Vec3 eye = ph.landmark("left_eye");
  Grid g;
  g.spacing = Vec3(0.5);
  g.origin = eye - Vec3(10.0);
  g.dims = Index3(41);
  for (ScalarType type : {ScalarType::F32, ScalarType::U8}) {
    const Volume v = truthVolume(ph, sim.bmode(), g, type, 2);
    EXPECT_NEAR(v.value(g.linear(20, 20, 20)), sim.bmode().displayLevel(Tissue::HardPlastic), 0.51);
    // Water above the face: the noise floor.
    const double water = sim.bmode().displayLevel(Tissue::Water);
    EXPECT_NEAR(v.value(g.linear(0, 0, 40)), water, 0.51);
    double lo = 255, hi = 0;
    bool between = false;
    for (std::size_t i = 0; i < g.voxelCount(); ++i) {
      const double x = v.value(i);
      lo = std::min(lo, x);
      hi = std::max(hi, x);
      between = between || (x > water + 5.0 && x < sim.bmode().displayLevel(Tissue::Vinyl) - 5.0);
    }
    EXPECT_GE(lo, 0.0);
    EXPECT_LE(hi, 255.0);
    EXPECT_TRUE(between) << "partial volume at the boundaries";
  }
  Grid huge = g;
  huge.dims = Index3(100000);
  EXPECT_THROW(truthVolume(ph, sim.bmode(), huge, ScalarType::F32, 1, 1 << 30), InputError);
}

TEST(Simulate, FitGridHoldsEveryFrame) {
  const SweepSimulator sim(settingsFor("doll"));
  std::vector<Mat4> poses;
  for (std::size_t i = 0; i < sim.frameCount(); ++i) poses.push_back(sim.imageToReference(i));
  const Grid g = fitGrid(poses, sim.probe().width, sim.probe().height, Vec3(1.0, 0.5, 2.0), 2.0);
  EXPECT_EQ(g.spacing, Vec3(1.0, 0.5, 2.0));
  const double w = sim.probe().width - 1, h = sim.probe().height - 1;
  for (const Mat4& m : poses)
    for (const Vec3 px : {Vec3(0, 0, 0), Vec3(w, 0, 0), Vec3(0, h, 0), Vec3(w, h, 0)}) {
      const Vec3 p = transformPoint(m, px);
      for (int a = 0; a < 3; ++a) {
        EXPECT_GE(p[a] - g.minCorner()[a], 2.0 - 1e-9);
        EXPECT_GE(g.maxCorner()[a] - p[a], 2.0 - 1e-9);
        EXPECT_LT(p[a] - g.minCorner()[a], 2.0 + 200.0);
      }
    }
}

TEST(Simulate, ThreadCountDoesNotChangeTheFrames) {
  SimSettings s = settingsFor("doll");
  s.sweep.maxFrames = 5;
  s.probe.widthPx = 96;
  s.probe.heightPx = 150;
  const SweepSimulator sim(s);
  std::vector<Frame> one, three;
  sim.run(1, [&](Frame&& f) { one.push_back(std::move(f)); });
  std::vector<std::size_t> progress;
  sim.run(3, [&](Frame&& f) { three.push_back(std::move(f)); }, [&](std::size_t done, std::size_t) { progress.push_back(done); });
  ASSERT_EQ(one.size(), 5u);
  ASSERT_EQ(three.size(), 5u);
  for (std::size_t i = 0; i < 5; ++i) {
    EXPECT_EQ(three[i].index, i);
    EXPECT_EQ(one[i].pixels, three[i].pixels);
  }
  EXPECT_EQ(progress, (std::vector<std::size_t>{1, 2, 3, 4, 5}));
  // An error in the sink stops the run and comes out.
  EXPECT_THROW(sim.run(2, [](Frame&&) { throw InputError("disk full"); }), InputError);
}

TEST(Simulate, CommandWritesReadablePlusData) {
  const fs::path dir = freshDir("e2e");
  int status = -1;
  const std::string out = runBinary("simulate -o " + dir.string() +
                                        " --set sim.sweep.max_frames=6 --set sim.probe.width_px=128"
                                        " --set sim.probe.height_px=200 --set output.preview_frames=3"
                                        " --set 'grid.spacing=[2.0, 2.0, 2.0]' --set sim.truth_type='\"uint8\"'",
                                    &status);
  ASSERT_EQ(status, 0) << out;
  for (const char* name : {"doll_sweep.igs.mha", "doll_config.xml", "doll_truth.mha", "settings.toml",
                           "frame_0000.png", "frame_0005.png"})
    EXPECT_TRUE(fs::exists(dir / name)) << name << "\n" << out;
  EXPECT_NE(out.find(dir.string()), std::string::npos) << "prints where it wrote";

  // The sequence reads back with the poses the simulator recorded.
  SimSettings s;
  s.sweep.maxFrames = 6;
  s.probe.widthPx = 128;
  s.probe.heightPx = 200;
  const SweepSimulator sim(s);
  SequenceInfo info;
  const std::vector<Frame> frames = readAllFrames((dir / "doll_sweep.igs.mha").string(), &info);
  ASSERT_EQ(frames.size(), 6u);
  EXPECT_TRUE(info.compressed);
  EXPECT_EQ(info.width, 128);
  EXPECT_EQ(info.height, 200);
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const FrameTransform* t = frames[i].findTransform("ProbeToTracker");
    ASSERT_TRUE(t);
    const Mat4 expected = sim.sweep().frames[i].probeToTracker;
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r) EXPECT_NEAR(t->matrix[c][r], expected[c][r], 1e-9);
    EXPECT_TRUE(frames[i].findField("ArmCounts"));
    EXPECT_NEAR(frames[i].timestamp, sim.sweep().frames[i].timestamp, 1e-9);
  }
  EXPECT_EQ(frames[2].pixels, sim.frame(2).pixels);

  // The config: ImageToProbe, and a VolumeReconstruction on the truth's grid.
  const PlusConfig cfg = readPlusConfig((dir / "doll_config.xml").string());
  const auto i2p = cfg.coordinates.get("Image", "Probe");
  ASSERT_TRUE(i2p);
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r) EXPECT_NEAR((*i2p)[c][r], sim.imageToProbe()[c][r], 1e-12);
  ASSERT_TRUE(cfg.volumeReconstruction);
  EXPECT_EQ(cfg.volumeReconstruction->outputSpacing, Vec3(2.0));
  const auto plan = cfg.planImageToReference({"ProbeToTracker", "ReferenceToTracker", "TrueProbeToTracker"});
  EXPECT_EQ(plan.frames.front(), "Image");
  EXPECT_EQ(plan.frames.back(), "Reference");
  const auto m = imageToReference(cfg, frames[1]);
  ASSERT_TRUE(m);
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r) EXPECT_NEAR((*m)[c][r], sim.imageToReference(1)[c][r], 1e-9);

  const Volume truth = readVolume((dir / "doll_truth.mha").string());
  EXPECT_EQ(truth.type, ScalarType::U8);
  EXPECT_EQ(truth.grid.spacing, Vec3(2.0));
  ASSERT_TRUE(cfg.volumeReconstruction->outputOrigin);
  EXPECT_NEAR(glm::length(*cfg.volumeReconstruction->outputOrigin - truth.grid.origin), 0.0, 1e-9);
  ASSERT_TRUE(cfg.volumeReconstruction->outputExtent);
  EXPECT_EQ((*cfg.volumeReconstruction->outputExtent)[1], truth.grid.dims.x - 1);

  const Image8 png = readImage8((dir / "frame_0005.png").string());
  EXPECT_EQ(png.width, 128);
  EXPECT_EQ(png.height, 200);

  std::ifstream toml(dir / "settings.toml");
  std::stringstream text;
  text << toml.rdbuf();
  EXPECT_NE(text.str().find("max_frames = 6"), std::string::npos);
  fs::remove_all(dir);
}

TEST(Simulate, CommandRefusesBadSettingsWithOneLine) {
  const fs::path dir = freshDir("bad");
  int status = -1;
  std::string out = runBinary("simulate -o " + dir.string() + " --set sim.phantom='\"teapot\"'", &status);
  EXPECT_EQ(status, 1) << out;
  EXPECT_NE(out.find("sim.phantom"), std::string::npos) << out;
  out = runBinary("simulate -o " + dir.string() + " --set sim.sweep.length_mm=1500", &status);
  EXPECT_EQ(status, 1) << out;
  EXPECT_NE(out.find("sim.sweep"), std::string::npos) << out;
  // A truth grid that cannot fit is refused before anything is simulated.
  out = runBinary("simulate -o " + dir.string() +
                      " --set grid.auto_extent=false --set 'grid.dims=[100000, 100000, 100000]'",
                  &status);
  EXPECT_EQ(status, 1) << out;
  EXPECT_FALSE(fs::exists(dir / "doll_sweep.igs.mha"));
  fs::remove_all(dir);
}
