// Probe calibration (calib/): the N-wire geometry against hand-computed
// points, the opening against a brute-force one, the segmentation on a drawn
// image with known dots, the fit on exact synthetic frames, the config's
// phantom and the calibrated config written back.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <random>

#include "analysis/nwire.hpp"
#include "analysis/probe_calibration.hpp"
#include "analysis/recording.hpp"
#include "analysis/wire_segmentation.hpp"
#include "core/error.hpp"
#include "formats/plus_config.hpp"

namespace pp5 {
namespace {

using calib::Vec2;
using glm::dvec3;

constexpr double kDeg = std::numbers::pi / 180.0;

PlusWire wire(const char* name, dvec3 a, dvec3 b) { return {name, a, b}; }

// The fCal 2.0 phantom's three N patterns (PLUS's PhantomDefinition).
std::vector<PlusNWirePattern> fcal2Patterns() {
  return {
      {{wire("7", {30, 0, 20}, {30, 40, 20}), wire("8", {55, 0, 20}, {35, 40, 20}), wire("9", {60, 0, 20}, {60, 40, 20})}},
      {{wire("4", {30, 0, 10}, {30, 40, 10}), wire("5", {35, 0, 10}, {55, 40, 10}), wire("6", {60, 0, 10}, {60, 40, 10})}},
      {{wire("1", {35, 0, 0}, {35, 40, 0}), wire("2", {55, 0, 0}, {40, 40, 0}), wire("3", {60, 0, 0}, {60, 40, 0})}},
  };
}

void expectNear(const dvec3& a, const dvec3& b, double tol) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(a.z, b.z, tol);
}

// ---- geometry ----

TEST(NWire, RatioAlong) {
  EXPECT_DOUBLE_EQ(calib::ratioAlong({0, 0}, {1, 0}, {4, 0}), 0.25);
  EXPECT_DOUBLE_EQ(calib::ratioAlong({2, 2}, {5, 6}, {8, 10}), 0.5);
  // Off the line: the projection.
  EXPECT_DOUBLE_EQ(calib::ratioAlong({0, 0}, {3, 1}, {4, 0}), 0.75);
}

TEST(NWire, SpacingsOfFcal2) {
  const calib::NWirePhantom ph(fcal2Patterns());
  ASSERT_EQ(ph.patternCount(), 3);
  EXPECT_DOUBLE_EQ(ph.outerSpacingMm(0), 30.0);
  EXPECT_DOUBLE_EQ(ph.outerSpacingMm(1), 30.0);
  EXPECT_DOUBLE_EQ(ph.outerSpacingMm(2), 25.0);
  EXPECT_DOUBLE_EQ(ph.planeDistanceMm(0), 10.0);
  EXPECT_DOUBLE_EQ(ph.planeDistanceMm(1), 10.0);
}

TEST(NWire, MiddleWirePointByHand) {
  const calib::NWirePhantom ph(fcal2Patterns());
  // A plane square to the wires at y = 10 cuts pattern 0's outer wires at
  // x = 30 and 60 and its diagonal (x = 55 - y / 2) at x = 50: u = 20 / 30.
  expectNear(ph.middleWirePoint(0, 2.0 / 3.0), {50.0, 10.0, 20.0}, 1e-9);
  // Pattern 1's diagonal runs the other way (x = 35 + y / 2): at y = 30, x = 50.
  expectNear(ph.middleWirePoint(1, 20.0 / 30.0), {50.0, 30.0, 10.0}, 1e-9);
  // An oblique line through (30, 5) and (60, 15): it meets x = 55 - y / 2 at
  // 30 + 30 s = 55 - (5 + 10 s) / 2, s = 22.5 / 35, so (49.2857..., 11.4285...).
  const double s = 22.5 / 35.0;
  expectNear(ph.middleWirePoint(0, s), {30.0 + 30.0 * s, 5.0 + 10.0 * s, 20.0}, 1e-9);
  // Pattern 2: outer wires at x = 35 and 60, diagonal x = 55 - 3 y / 8; at
  // y = 8 the diagonal is at x = 52, u = 17 / 25.
  expectNear(ph.middleWirePoint(2, 17.0 / 25.0), {52.0, 8.0, 0.0}, 1e-9);
}

// ---- the opening ----

TEST(WireSegmentation, OpeningEqualsBruteForce) {
  std::mt19937 rng(7);
  for (int radius : {0, 1, 2, 3, 5}) {
    const int w = 41, h = 29;
    std::vector<std::uint8_t> img(static_cast<std::size_t>(w * h));
    for (auto& v : img) v = static_cast<std::uint8_t>(rng() % 256);
    auto at = [&](const std::vector<std::uint8_t>& im, int x, int y) { return im[static_cast<std::size_t>(y * w + x)]; };
    auto morph = [&](const std::vector<std::uint8_t>& in, bool erode) {
      std::vector<std::uint8_t> out(in.size());
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          int v = erode ? 255 : 0;
          for (int dy = -radius; dy <= radius; ++dy)
            for (int dx = -radius; dx <= radius; ++dx) {
              if (dx * dx + dy * dy > radius * radius) continue;
              const int xx = x + dx, yy = y + dy;
              if (xx < 0 || yy < 0 || xx >= w || yy >= h) continue;
              v = erode ? std::min<int>(v, at(in, xx, yy)) : std::max<int>(v, at(in, xx, yy));
            }
          out[static_cast<std::size_t>(y * w + x)] = static_cast<std::uint8_t>(v);
        }
      return out;
    };
    EXPECT_EQ(calib::openWithDisc(img, w, h, radius), morph(morph(img, true), false)) << "radius " << radius;
  }
}

TEST(WireSegmentation, OpeningRemovesSpecksKeepsDots) {
  const int w = 60, h = 40;
  std::vector<std::uint8_t> img(static_cast<std::size_t>(w * h), 0);
  img[static_cast<std::size_t>(10 * w + 10)] = 250;  // a speck
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      if ((x - 40) * (x - 40) + (y - 20) * (y - 20) <= 16) img[static_cast<std::size_t>(y * w + x)] = 200;  // a dot
  const auto out = calib::openWithDisc(img, w, h, 3);
  EXPECT_EQ(out[static_cast<std::size_t>(10 * w + 10)], 0);
  EXPECT_EQ(out[static_cast<std::size_t>(20 * w + 40)], 200);
}

// ---- the segmentation ----

PlusSegmentation drawnSettings() {
  PlusSegmentation s;
  s.approximateSpacingMmPerPixel = 0.2;
  s.morphologicalOpeningCircleRadiusMm = 0.4;  // 2 pixels
  s.clipRectangleOrigin = {5, 5};
  s.clipRectangleSize = {490, 390};
  return s;
}

// Gaussian dots (sd 2 px) on black, with a wall and a stray dot.
Frame drawnFrame(const std::vector<Vec2>& dots) {
  Frame f;
  f.allocate(500, 400, PixelType::U8);
  std::vector<double> acc(static_cast<std::size_t>(500 * 400), 0.0);
  for (const Vec2& d : dots)
    for (int y = 0; y < 400; ++y)
      for (int x = 0; x < 500; ++x) {
        const double r2 = (x - d.x) * (x - d.x) + (y - d.y) * (y - d.y);
        if (r2 < 100.0) acc[static_cast<std::size_t>(y * 500 + x)] += 200.0 * std::exp(-r2 / 8.0);
      }
  for (int y = 348; y < 353; ++y)
    for (int x = 20; x < 480; ++x) acc[static_cast<std::size_t>(y * 500 + x)] = 180.0;  // the phantom's floor
  for (std::size_t i = 0; i < acc.size(); ++i) f.pixels[i] = static_cast<std::uint8_t>(std::min(255.0, std::round(acc[i])));
  return f;
}

TEST(WireSegmentation, FindsDrawnPattern) {
  const calib::NWirePhantom ph(fcal2Patterns());
  // Three rows 10 mm (50 px) apart; outer dots 30, 30 and 25 mm (150, 150,
  // 125 px) apart; the middle dots where the diagonals would be.
  const std::vector<std::array<Vec2, 3>> truth = {
      {Vec2(100.4, 100.3), Vec2(200.7, 100.3), Vec2(250.4, 100.3)},
      {Vec2(100.2, 150.6), Vec2(130.5, 150.6), Vec2(250.2, 150.6)},
      {Vec2(125.5, 200.8), Vec2(210.3, 200.8), Vec2(250.5, 200.8)},
  };
  std::vector<Vec2> dots;
  for (const auto& row : truth) dots.insert(dots.end(), row.begin(), row.end());
  dots.push_back({400.0, 300.0});  // a stray echo
  const auto seg = calib::segmentWires(drawnFrame(dots), drawnSettings(), ph);
  ASSERT_TRUE(seg.found) << seg.why;
  EXPECT_EQ(seg.candidates.size(), 10u);  // nine dots and the stray one; the floor is too wide to be a dot
  ASSERT_EQ(seg.patterns.size(), 3u);
  for (std::size_t k = 0; k < 3; ++k)
    for (std::size_t i = 0; i < 3; ++i) {
      EXPECT_NEAR(seg.patterns[k][i].x, truth[k][i].x, 0.1) << "pattern " << k << " dot " << i;
      EXPECT_NEAR(seg.patterns[k][i].y, truth[k][i].y, 0.1) << "pattern " << k << " dot " << i;
    }
}

TEST(WireSegmentation, ReportsWhatIsMissing) {
  const calib::NWirePhantom ph(fcal2Patterns());
  // Only two rows: six dots, so no pattern set.
  const std::vector<Vec2> dots = {{100, 100}, {200, 100}, {250, 100}, {100, 150}, {130, 150}, {250, 150}};
  const auto seg = calib::segmentWires(drawnFrame(dots), drawnSettings(), ph);
  EXPECT_FALSE(seg.found);
  EXPECT_NE(seg.why.find("6 dot candidates, 9 needed"), std::string::npos) << seg.why;
  // Nine dots, but the rows 20 mm apart instead of 10: no set fits the phantom.
  std::vector<Vec2> far = {{100, 60}, {200, 60}, {250, 60}, {100, 160}, {130, 160}, {250, 160},
                           {125, 260}, {210, 260}, {250, 260}};
  const auto seg2 = calib::segmentWires(drawnFrame(far), drawnSettings(), ph);
  EXPECT_FALSE(seg2.found);
  EXPECT_NE(seg2.why.find("fit the phantom"), std::string::npos) << seg2.why;
  // A blank frame.
  Frame blank;
  blank.allocate(100, 80, PixelType::U8);
  EXPECT_FALSE(calib::segmentWires(blank, drawnSettings(), ph).found);
  Frame wide;
  wide.allocate(100, 80, PixelType::U16);
  EXPECT_THROW(calib::segmentWires(wide, drawnSettings(), ph), InputError);
}

// ---- the fit ----

// Exact frames: the image plane of a known ImageToProbe, placed over the
// phantom by poses that slide along the wires and tilt, cut every wire at a
// point whose pixel is computed, not measured.
struct Synthetic {
  Mat4 imageToProbe{1.0};
  std::vector<calib::CalibrationFrame> frames;
};

Synthetic synthetic(const calib::NWirePhantom& ph, bool mirrored, int n) {
  Synthetic s;
  const Mat4 rigid = translation({11.0, 47.0, -3.0}) * rotationAxisAngle(glm::normalize(dvec3(0.3, -0.2, 0.9)), 75.0 * kDeg);
  const double sx = 0.0795, sy = 0.0745;
  s.imageToProbe = rigid * scaling({sx, sy, 0.5 * (sx + sy)});
  for (int i = 0; i < n; ++i) {
    const double t = static_cast<double>(i) / (n - 1);
    // Image x along phantom +x (or -x when mirrored), image y down (-z).
    Mat4 look(1.0);
    look[0] = glm::dvec4(mirrored ? -1 : 1, 0, 0, 0);
    look[1] = glm::dvec4(0, 0, -1, 0);
    look[2] = glm::dvec4(0, mirrored ? -1 : 1, 0, 0);
    const Mat4 tilt = rotationAxisAngle({1, 0, 0}, 6.0 * kDeg * std::sin(7.0 * t)) *
                      rotationAxisAngle({0, 1, 0}, 5.0 * kDeg * std::cos(5.0 * t)) *
                      rotationAxisAngle({0, 0, 1}, 7.0 * kDeg * std::sin(3.0 * t + 1.0));
    const dvec3 origin(mirrored ? 77.0 : 13.0, 8.0 + 24.0 * t, 42.0);
    // ImageToPhantom = pose * diag(sx, sy): pixel (0, 0) at `origin`.
    const Mat4 imageToPhantomRigid = translation(origin) * tilt * look;
    const Mat4 probeToPhantom = imageToPhantomRigid * affineInverse(rigid);
    const Mat4 phantomToProbe = affineInverse(probeToPhantom);
    const dvec3 o = transformPoint(imageToPhantomRigid, dvec3(0.0));
    const dvec3 u = transformVector(imageToPhantomRigid, {1, 0, 0});
    const dvec3 v = transformVector(imageToPhantomRigid, {0, 1, 0});
    const dvec3 nrm = transformVector(imageToPhantomRigid, {0, 0, 1});
    calib::CalibrationFrame f;
    f.frameIndex = static_cast<std::size_t>(i);
    f.phantomToProbe = phantomToProbe;
    for (int k = 0; k < ph.patternCount(); ++k) {
      std::array<Vec2, 3> d;
      for (int w = 0; w < 3; ++w) {
        const dvec3 a = ph.wirePoint(k, w), dir = ph.wireDirection(k, w);
        const double sAlong = glm::dot(o - a, nrm) / glm::dot(dir, nrm);
        const dvec3 x = a + sAlong * dir;
        d[static_cast<std::size_t>(w)] = Vec2(glm::dot(x - o, u) / sx, glm::dot(x - o, v) / sy);
      }
      std::sort(d.begin(), d.end(), [](const Vec2& p, const Vec2& q) { return p.x < q.x; });
      f.dots.push_back(d);
    }
    s.frames.push_back(f);
  }
  return s;
}

TEST(ProbeCalibration, RecoversExactCalibration) {
  const calib::NWirePhantom ph(fcal2Patterns());
  for (bool mirrored : {false, true}) {
    const Synthetic s = synthetic(ph, mirrored, 30);
    for (auto model : {calib::CalibrationModel::Affine, calib::CalibrationModel::RigidScale})
      for (auto refine : {calib::CalibrationRefinement::None, calib::CalibrationRefinement::MeanDistance,
                          calib::CalibrationRefinement::AllWires}) {
        calib::CalibrationOptions o;
        o.model = model;
        o.refinement = refine;
        const auto r = calib::calibrateProbe(ph, s.frames, o);
        const std::string what = ::testing::PrintToString(static_cast<int>(model)) + "/" +
                                 ::testing::PrintToString(static_cast<int>(refine)) + (mirrored ? " mirrored" : "");
        EXPECT_EQ(r.wire0OnRight, mirrored) << what;
        EXPECT_LT(calib::cornerDistanceMm(r.imageToProbe, s.imageToProbe, 820, 616), 1e-5) << what;
        EXPECT_LT(r.error.max, 1e-5) << what;
        EXPECT_EQ(r.pointsRejected, 0u) << what;
        for (double e : calib::wireErrors(ph, s.frames, r.imageToProbe, r.wire0OnRight)) EXPECT_LT(e, 1e-5) << what;
        // The elevation column: square to the image axes, their mean length.
        EXPECT_NEAR(glm::dot(dvec3(r.imageToProbe[2]), dvec3(r.imageToProbe[0])), 0.0, 1e-9) << what;
        EXPECT_NEAR(glm::length(dvec3(r.imageToProbe[2])), 0.5 * (0.0795 + 0.0745), 1e-7) << what;
      }
  }
}

TEST(ProbeCalibration, RejectsAWrongDot) {
  const calib::NWirePhantom ph(fcal2Patterns());
  Synthetic s = synthetic(ph, false, 40);
  // One middle dot 40 pixels (3 mm) off: rejected, and the rest fit exactly.
  s.frames[17].dots[1][1].x += 40.0;
  calib::CalibrationOptions o;
  o.refinement = calib::CalibrationRefinement::None;
  const auto r = calib::calibrateProbe(ph, s.frames, o);
  EXPECT_EQ(r.pointsRejected, 1u);
  EXPECT_LT(calib::cornerDistanceMm(r.imageToProbe, s.imageToProbe, 820, 616), 1e-5);
  // Per wire, only pattern 1's middle wire (index 4) shows the bad dot: 3 mm
  // or more in one of 40 frames.
  const auto w = calib::wireErrors(ph, s.frames, r.imageToProbe, r.wire0OnRight);
  ASSERT_EQ(w.size(), 9u);
  for (std::size_t i = 0; i < 9; ++i)
    if (i == 4)
      EXPECT_GT(w[i], 0.05);
    else
      EXPECT_LT(w[i], 1e-5) << i;
}

TEST(ProbeCalibration, RefusesTooFewFramesAndNoMotion) {
  const calib::NWirePhantom ph(fcal2Patterns());
  Synthetic s = synthetic(ph, false, 30);
  std::vector<calib::CalibrationFrame> few(s.frames.begin(), s.frames.begin() + 5);
  try {
    calib::calibrateProbe(ph, few);
    FAIL() << "5 frames calibrated";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("found in 5 frames"), std::string::npos) << e.what();
  }
  std::vector<calib::CalibrationFrame> still(20, s.frames[3]);
  try {
    calib::calibrateProbe(ph, still);
    FAIL() << "a still probe calibrated";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("too little probe motion"), std::string::npos) << e.what();
  }
}

// ---- the config ----

const std::string kData = PP5_DATA_DIR;

TEST(CalibrationConfig, ReadsBothFcalPhantoms) {
  const PlusConfig c2 = readPlusConfig(kData + "/PlusDeviceSet_fCal_Sim_SpatialCalibration_2.0.xml");
  ASSERT_TRUE(c2.phantomDefinition && c2.segmentation);
  ASSERT_EQ(c2.phantomDefinition->patterns.size(), 3u);
  const auto mine = fcal2Patterns();
  for (std::size_t k = 0; k < 3; ++k)
    for (std::size_t w = 0; w < 3; ++w) {
      EXPECT_EQ(c2.phantomDefinition->patterns[k].wires[w].front, mine[k].wires[w].front) << k << " " << w;
      EXPECT_EQ(c2.phantomDefinition->patterns[k].wires[w].back, mine[k].wires[w].back) << k << " " << w;
    }
  EXPECT_EQ(c2.phantomDefinition->patterns[1].wires[1].name, "5:H3_l3");
  EXPECT_EQ(c2.phantomDefinition->patterns[1].wires[1].back, dvec3(55, 40, 10));
  EXPECT_EQ(c2.phantomDefinition->version, "2.0");
  EXPECT_DOUBLE_EQ(c2.segmentation->approximateSpacingMmPerPixel, 0.078);
  EXPECT_EQ(c2.segmentation->clipRectangleOrigin, glm::ivec2(27, 27));
  EXPECT_EQ(c2.segmentation->clipRectangleSize, glm::ivec2(766, 562));
  EXPECT_EQ(c2.segmentation->numberOfMaximumFiducialPointCandidates, 20);
  EXPECT_EQ(c2.probeCalibrationFrames.phantom, "Phantom");
  const PlusConfig c1 = readPlusConfig(kData + "/PlusDeviceSet_fCal_Sim_SpatialCalibration_1.2.xml");
  ASSERT_TRUE(c1.phantomDefinition);
  const calib::NWirePhantom p1(c1.phantomDefinition->patterns);
  EXPECT_DOUBLE_EQ(p1.planeDistanceMm(0), 5.0);
  EXPECT_DOUBLE_EQ(p1.outerSpacingMm(0), 25.0);  // x = 20 and 45
  EXPECT_DOUBLE_EQ(p1.outerSpacingMm(1), 30.0);  // x = 20 and 50
  // A config with no phantom has none.
  EXPECT_FALSE(readPlusConfig(kData + "/BoneUltrasound_L14_config.xml").phantomDefinition);
  // PLUS's older spelling, <NWire> for <Pattern Type="NWire"> (fCal 1.0, two patterns).
  const PlusConfig c0 = readPlusConfig(kData + "/PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml");
  ASSERT_TRUE(c0.phantomDefinition) << c0.calibrationError;
  ASSERT_EQ(c0.phantomDefinition->patterns.size(), 2u);
  EXPECT_EQ(c0.phantomDefinition->patterns[1].wires[1].name, "J4_f4");
  EXPECT_EQ(c0.phantomDefinition->patterns[1].wires[1].front, dvec3(45, 0, 0));
}

std::string writeTemp(const std::string& name, const std::string& text) {
  const std::string p = (std::filesystem::temp_directory_path() / name).string();
  std::ofstream(p) << text;
  return p;
}

TEST(CalibrationConfig, RefusesPatternsThatAreNotN) {
  auto cfg = [](const char* wires) {
    return std::string("<PlusConfiguration><PhantomDefinition><Geometry><Pattern Type=\"NWire\">") + wires +
           "</Pattern></Geometry></PhantomDefinition></PlusConfiguration>";
  };
  // The config still reads (a reconstruction does not need the phantom); the
  // calibration is refused with the reason.
  auto fails = [&](const char* wires, const char* needle) {
    const std::string p = writeTemp("pp5_calib_bad.xml", cfg(wires));
    const PlusConfig c = readPlusConfig(p);
    EXPECT_FALSE(c.phantomDefinition);
    EXPECT_NE(c.calibrationError.find(needle), std::string::npos) << c.calibrationError;
    try {
      calib::phantomOf(c);
      ADD_FAILURE() << "accepted: " << wires;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  fails("<Wire EndPointFront=\"0 0 0\" EndPointBack=\"0 40 0\"/><Wire EndPointFront=\"20 0 0\" EndPointBack=\"5 40 0\"/>"
        "<Wire EndPointFront=\"25 0 0\" EndPointBack=\"35 40 0\"/>",
        "not parallel");
  fails("<Wire EndPointFront=\"0 0 0\" EndPointBack=\"0 40 0\"/><Wire EndPointFront=\"20 0 5\" EndPointBack=\"5 40 0\"/>"
        "<Wire EndPointFront=\"25 0 0\" EndPointBack=\"25 40 0\"/>",
        "not in the plane");
  fails("<Wire EndPointFront=\"0 0 0\" EndPointBack=\"0 40 0\"/><Wire EndPointFront=\"20 0 0\" EndPointBack=\"20 40 0\"/>"
        "<Wire EndPointFront=\"25 0 0\" EndPointBack=\"25 40 0\"/>",
        "parallel to the outer");
  fails("<Wire EndPointFront=\"0 0 0\" EndPointBack=\"0 40 0\"/><Wire EndPointFront=\"20 0 0\" EndPointBack=\"40 40 0\"/>"
        "<Wire EndPointFront=\"25 0 0\" EndPointBack=\"25 40 0\"/>",
        "leaves the strip");
  fails("<Wire EndPointFront=\"0 0 0\" EndPointBack=\"0 40 0\"/><Wire EndPointFront=\"20 0 0\" EndPointBack=\"5 40 0\"/>",
        "has 2 wires");
}

TEST(CalibrationConfig, WritesTheCalibrationBack) {
  // The fCal volume reconstruction config already has an ImageToProbe: it is
  // replaced, and everything else is kept.
  const std::string src = kData + "/PlusDeviceSet_fCal_Sim_VolumeReconstruction.xml";
  const PlusConfig before = readPlusConfig(src);
  const std::string out = (std::filesystem::temp_directory_path() / "pp5_calibrated.xml").string();
  const Mat4 m = translation({1.5, -2.25, 3.0}) * scaling({0.08, 0.075, 0.0775});
  writePlusConfigWithTransform(src, out, {"Image", "Probe", m}, 0.4321, "112726_101500");
  const PlusConfig after = readPlusConfig(out);
  EXPECT_EQ(*after.coordinates.get("Image", "Probe"), m);
  EXPECT_EQ(after.transforms.size(), before.transforms.size());
  EXPECT_EQ(*after.coordinates.get("Phantom", "Reference"), *before.coordinates.get("Phantom", "Reference"));
  EXPECT_EQ(after.volumeReconstruction, before.volumeReconstruction);
  EXPECT_EQ(after.phantomDefinition, before.phantomDefinition);
  std::ifstream in(out);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("Error=\"0.4321\""), std::string::npos);
  EXPECT_NE(text.find("Date=\"112726_101500\""), std::string::npos);
  // Written as ProbeToImage before: replaced all the same.
  const std::string inverse = writeTemp(
      "pp5_probe_to_image.xml",
      "<PlusConfiguration><CoordinateDefinitions><Transform From=\"Probe\" To=\"Image\" Matrix=\"1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\"/>"
      "</CoordinateDefinitions></PlusConfiguration>");
  writePlusConfigWithTransform(inverse, out, {"Image", "Probe", m}, 0.5, "x");
  const PlusConfig again = readPlusConfig(out);
  ASSERT_EQ(again.transforms.size(), 1u);
  EXPECT_EQ(again.transforms[0].from, "Image");
  std::filesystem::remove(out);
}

}  // namespace
}  // namespace pp5
