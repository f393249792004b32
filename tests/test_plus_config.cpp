// PLUS device-set configuration XML: every config of the PLUS test data, the
// Image -> Reference chain, error messages, and the write/read round trip.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include "core/error.hpp"
#include "core/frame.hpp"
#include "formats/plus_config.hpp"

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::StartsWith;

namespace pp5 {
namespace {

const std::string kData = PP5_DATA_DIR;

std::string dataFile(const std::string& name) { return kData + "/" + name; }

std::vector<std::string> allConfigs() {
  std::vector<std::string> out;
  for (const auto& e : fs::directory_iterator(kData))
    if (e.is_regular_file() && e.path().extension() == ".xml") out.push_back(e.path().string());
  std::sort(out.begin(), out.end());
  return out;
}

// A spatial-calibration config (fCal's, named so by PLUS): its ImageToProbe
// is what the calibration finds, so the file has none.
bool isCalibrationConfig(const std::string& path) {
  return fs::path(path).filename().string().find("_SpatialCalibration_") != std::string::npos;
}

// The text of an InputError thrown by f (fails the test when none is thrown).
std::string inputErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  ADD_FAILURE() << "no InputError was thrown";
  return {};
}

// MetaIO header value "Key = Value" of a sequence file.
std::string headerValue(const std::string& file, const std::string& key) {
  std::ifstream in(file, std::ios::binary);
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("ElementDataFile", 0) == 0) break;
    if (line.rfind(key + " = ", 0) == 0) {
      std::string v = line.substr(key.size() + 3);
      while (!v.empty() && (v.back() == '\r' || v.back() == ' ')) v.pop_back();
      return v;
    }
  }
  return {};
}

Mat4 parsed(const std::string& text) {
  std::string why;
  const auto m = parseRowMajor(text, &why);
  EXPECT_TRUE(m) << why;
  return m.value_or(Mat4(0.0));
}

void expectNear(const Mat4& a, const Mat4& b, double tol) {
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r) EXPECT_NEAR(a[c][r], b[c][r], tol) << "row " << r << " col " << c;
}

// A scratch folder per test, removed afterwards.
class TempDir : public ::testing::Test {
protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() /
           (std::string("pp5_plus_config_") + std::to_string(::getpid()) + "_" + info->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string write(const std::string& name, const std::string& text) const {
    const std::string p = (dir_ / name).string();
    std::ofstream(p, std::ios::binary) << text;
    return p;
  }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  // A small valid config with `recon` as the VolumeReconstruction attributes.
  std::string config(const std::string& name, const std::string& recon, const std::string& defs = kImageToProbe,
                     const std::string& children = "") const {
    std::string text = "<PlusConfiguration version=\"2.1\">\n  <CoordinateDefinitions>\n" + defs +
                       "  </CoordinateDefinitions>\n  <VolumeReconstruction " + recon;
    text += children.empty() ? " />\n" : ">\n" + children + "  </VolumeReconstruction>\n";
    text += "</PlusConfiguration>\n";
    return write(name, text);
  }

  static inline const std::string kImageToProbe =
      "    <Transform From=\"Image\" To=\"Probe\" Matrix=\"0.1 0 0 1  0 0.1 0 2  0 0 0.1 3  0 0 0 1\" />\n";

  fs::path dir_;
};

// ---------------------------------------------------------------------------
// The PLUS test configs

TEST(PlusConfigData, EveryConfigReads) {
  const auto files = allConfigs();
  ASSERT_GE(files.size(), 12u) << "PLUS test configs missing from " << kData;
  for (const auto& f : files) {
    SCOPED_TRACE(f);
    PlusConfig cfg;
    ASSERT_NO_THROW(cfg = readPlusConfig(f));
    EXPECT_EQ(cfg.path, f);
    EXPECT_FALSE(cfg.transforms.empty());
    // Every one of them carries a VolumeReconstruction element, at the top
    // level or inside a VirtualVolumeReconstructor device.
    ASSERT_TRUE(cfg.volumeReconstruction);
    EXPECT_GT(cfg.volumeReconstruction->outputSpacing.x, 0.0);
    // The calibration reaches Probe, possibly through intermediate frames;
    // a probe-calibration config has no calibration yet.
    EXPECT_EQ(cfg.coordinates.get("Image", "Probe").has_value(), !isCalibrationConfig(f));
  }
}

TEST(PlusConfigData, NnMeanCalibrationAndSettings) {
  const auto cfg = readPlusConfig(dataFile("PlusDeviceSet_VolumeReconstructionOnly_SpinePhantom_NN_MEAN.xml"));
  const Mat4 imageToProbe = parsed(
      "-0.00157821  0.0785919   -0.00803285  15.3978 "
      "-0.0839128   0.00372697   0.0153803   49.5705 "
      " 0.0159024   0.00714276   0.0803604   -8.63446 "
      " 0           0            0            1");
  EXPECT_EQ(cfg.coordinates.get("Image", "Probe"), imageToProbe);  // exact: same text, same parser
  EXPECT_EQ(imageToProbe[3], Vec4(15.3978, 49.5705, -8.63446, 1.0));
  EXPECT_EQ(imageToProbe[0][1], -0.0839128);
  ASSERT_EQ(cfg.transforms.size(), 2u);
  EXPECT_EQ(cfg.transforms[0], (PlusConfigTransform{"Image", "Probe", imageToProbe}));
  EXPECT_EQ(cfg.transforms[1].from, "Phantom");
  EXPECT_EQ(cfg.transforms[1].to, "Reference");
  EXPECT_EQ(cfg.transforms[1].matrix[3], Vec4(11.9823, -37.1153, -85.3543, 1.0));

  ASSERT_TRUE(cfg.volumeReconstruction);
  const auto& v = *cfg.volumeReconstruction;
  EXPECT_EQ(v.imageCoordinateFrame, "Image");
  EXPECT_EQ(v.referenceCoordinateFrame, "Reference");
  EXPECT_EQ(v.outputSpacing, Vec3(0.5, 0.5, 0.5));
  EXPECT_FALSE(v.outputOrigin);
  EXPECT_FALSE(v.outputExtent);
  EXPECT_EQ(v.clipRectangleOrigin, glm::ivec2(0, 0));
  EXPECT_EQ(v.clipRectangleSize, glm::ivec2(820, 616));
  EXPECT_FALSE(v.fanAnglesDeg);
  EXPECT_EQ(v.interpolation, PlusInterpolation::NearestNeighbor);
  EXPECT_EQ(v.optimization, PlusOptimization::Full);
  EXPECT_EQ(v.compounding, PlusCompounding::Mean);
  EXPECT_EQ(v.numberOfThreads, 1);
  EXPECT_TRUE(v.fillHoles);
  ASSERT_EQ(v.holeFilling.size(), 1u);
  EXPECT_EQ(v.holeFilling[0].type, PlusHoleFillingType::Stick);
  EXPECT_EQ(v.holeFilling[0].stickLengthLimit, 9);
  EXPECT_EQ(v.holeFilling[0].numberOfSticksToUse, 1);
  EXPECT_EQ(v.skipInterval, 1);
  EXPECT_FALSE(v.pixelRejectionThreshold);
}

TEST(PlusConfigData, OtherSpinePhantomVariants) {
  {
    const auto v = readPlusConfig(dataFile("PlusDeviceSet_VolumeReconstructionOnly_SpinePhantom_LN_MAXI.xml"))
                       .volumeReconstruction.value();
    EXPECT_EQ(v.interpolation, PlusInterpolation::Linear);
    EXPECT_EQ(v.compounding, PlusCompounding::Maximum);
    EXPECT_FALSE(v.fillHoles);
    EXPECT_TRUE(v.holeFilling.empty());
  }
  {
    const auto v = readPlusConfig(dataFile("PlusDeviceSet_VolumeReconstructionOnly_SpinePhantom_LN_LATE.xml"))
                       .volumeReconstruction.value();
    EXPECT_EQ(v.interpolation, PlusInterpolation::Linear);
    EXPECT_EQ(v.compounding, PlusCompounding::Latest);
  }
  {
    const auto v = readPlusConfig(dataFile("PlusDeviceSet_VolumeReconstructionOnly_SpinePhantom_NN_MAXI.xml"))
                       .volumeReconstruction.value();
    EXPECT_EQ(v.interpolation, PlusInterpolation::NearestNeighbor);
    EXPECT_EQ(v.compounding, PlusCompounding::Maximum);
    ASSERT_EQ(v.holeFilling.size(), 1u);
    EXPECT_EQ(v.holeFilling[0].type, PlusHoleFillingType::Stick);
  }
  {
    const auto v = readPlusConfig(dataFile("PlusDeviceSet_SpinePhantomFreehandReconstructionOnly.xml"))
                       .volumeReconstruction.value();
    EXPECT_EQ(v.interpolation, PlusInterpolation::Linear);
    EXPECT_EQ(v.compounding, PlusCompounding::Mean);
    EXPECT_TRUE(v.fillHoles);
  }
}

TEST(PlusConfigData, TrusFanClipping) {
  for (const char* name : {"PlusDeviceSet_VolumeReconstructionOnly_SonixRP_TRUS_D70mm_LN_MEAN.xml",
                           "PlusDeviceSet_VolumeReconstructionOnly_SonixRP_TRUS_D70mm_NN_LATE.xml"}) {
    SCOPED_TRACE(name);
    const auto v = readPlusConfig(dataFile(name)).volumeReconstruction.value();
    EXPECT_EQ(v.clipRectangleOrigin, glm::ivec2(192, 16));
    EXPECT_EQ(v.clipRectangleSize, glm::ivec2(420, 580));
    EXPECT_EQ(v.fanAnglesDeg, glm::dvec2(-45, 45));
    EXPECT_EQ(v.fanOriginPixel, glm::dvec2(380, 20));
    EXPECT_EQ(v.fanRadiusStartPixel, 120.0);
    EXPECT_EQ(v.fanRadiusStopPixel, 360.0);
    EXPECT_FALSE(v.enableFanAnglesAutoDetect);
  }
  const auto late = readPlusConfig(dataFile("PlusDeviceSet_VolumeReconstructionOnly_SonixRP_TRUS_D70mm_NN_LATE.xml"))
                        .volumeReconstruction.value();
  EXPECT_EQ(late.compounding, PlusCompounding::Latest);
  EXPECT_EQ(late.interpolation, PlusInterpolation::NearestNeighbor);
  EXPECT_FALSE(late.fillHoles);
}

TEST(PlusConfigData, LegacyCompoundingOnAndMixedCase) {
  // Compounding="On" FillHoles="Off", written by an older PLUS.
  const auto cfg = readPlusConfig(dataFile("BoneUltrasound_L14_config.xml"));
  const auto& v = cfg.volumeReconstruction.value();
  EXPECT_EQ(v.compounding, PlusCompounding::Mean);
  EXPECT_FALSE(v.fillHoles);
  EXPECT_EQ(v.interpolation, PlusInterpolation::Linear);
  // Tab-separated matrix over several lines.
  EXPECT_EQ(cfg.coordinates.get("Image", "Probe").value()[3], Vec4(12.74, 50.76, -0.5, 1.0));
}

TEST(PlusConfigData, OpenIGTLinkCommandsTestNestedReconstructionAndImageFullChain) {
  const auto cfg = readPlusConfig(dataFile("PlusDeviceSet_OpenIGTLinkCommandsTest.xml"));
  EXPECT_THAT(cfg.deviceSetName, StartsWith("TEST PlusServer remote control"));
  EXPECT_THAT(cfg.deviceSetDescription, StartsWith("Read data from file"));
  const auto& v = cfg.volumeReconstruction.value();  // inside DataCollection/Device
  EXPECT_EQ(v.imageCoordinateFrame, "Image");
  EXPECT_EQ(v.referenceCoordinateFrame, "Reference");
  EXPECT_EQ(v.outputOrigin, Vec3(-10, -128, -36));
  EXPECT_EQ(v.outputExtent, (std::array<int, 6>{0, 20, 0, 15, 0, 12}));
  EXPECT_EQ(v.outputSpacing, Vec3(1, 1, 1));
  EXPECT_EQ(v.clipRectangleSize, glm::ivec2(200, 150));
  EXPECT_EQ(v.optimization, PlusOptimization::None);
  EXPECT_EQ(v.numberOfThreads, 2);

  // The cropped Image reaches Probe through ImageFull.
  EXPECT_EQ(cfg.coordinates.path("Image", "Probe"), (std::vector<std::string>{"Image", "ImageFull", "Probe"}));
  const Mat4 imageToImageFull = parsed("1 0 0 335  0 1 0 285  0 0 1 0  0 0 0 1");
  const Mat4 imageFullToProbe = parsed(
      "-0.0094 -0.0739 -0.0028 -103.5322  0.0774 -0.0076 -0.0049 -43.1227  0.0046 -0.0032 0.0760 -93.3  0 0 0 1");
  expectNear(cfg.coordinates.get("Image", "Probe").value(), imageFullToProbe * imageToImageFull, 1e-12);
  EXPECT_EQ(cfg.coordinates.get("StylusTip", "Stylus").value()[3], Vec4(203.772, -12.283, 1.17469, 1.0));
  EXPECT_EQ(cfg.transforms.size(), 5u);
}

TEST(PlusConfigData, ServerSimLiveReconstructionBox) {
  const auto v = readPlusConfig(dataFile("PlusDeviceSet_Server_Sim_NwirePhantom.xml")).volumeReconstruction.value();
  EXPECT_EQ(v.outputOrigin, Vec3(-15, -15, 30));
  EXPECT_EQ(v.outputExtent, (std::array<int, 6>{0, 300, 0, 300, 0, 300}));
  EXPECT_EQ(v.outputSpacing, Vec3(0.15, 0.15, 0.15));
}

// Every config reaches Reference from Image once the sequence supplies
// ProbeToTracker and ReferenceToTracker: all of them calibrate Image (directly
// or through ImageFull) to Probe.
TEST(PlusConfigData, PlanImageToReferenceForEveryConfig) {
  const std::vector<std::string> perFrame{"ProbeToTracker", "ReferenceToTracker", "StylusToTracker"};
  for (const auto& f : allConfigs()) {
    SCOPED_TRACE(f);
    const auto cfg = readPlusConfig(f);
    PlusConfig::ChainPlan plan;
    if (isCalibrationConfig(f)) {
      // No ImageToProbe: no chain, and a message that names the missing link.
      const std::string m = inputErrorOf([&] { plan = cfg.planImageToReference(perFrame); });
      EXPECT_NE(m.find("Image"), std::string::npos) << m;
      continue;
    }
    ASSERT_NO_THROW(plan = cfg.planImageToReference(perFrame));
    if (f.find("OpenIGTLinkCommandsTest") != std::string::npos)
      EXPECT_EQ(plan.frames, (std::vector<std::string>{"Image", "ImageFull", "Probe", "Tracker", "Reference"}));
    else
      EXPECT_EQ(plan.frames, (std::vector<std::string>{"Image", "Probe", "Tracker", "Reference"}));
    EXPECT_EQ(plan.perFrameTransforms, (std::vector<std::string>{"ProbeToTracker", "ReferenceToTracker"}));
  }
}

TEST(PlusConfigData, ImageToReferenceOfSpinePhantomFrame0) {
  const auto cfg = readPlusConfig(dataFile("PlusDeviceSet_VolumeReconstructionOnly_SpinePhantom_NN_MEAN.xml"));
  // Frame 0 of SpinePhantomFreehand.igs.mha, as its header writes them.
  const std::string probeText =
      "0.231245 0.951424 -0.203269 172.641 -0.127436 -0.17751 -0.975833 -98.0022 -0.964513 0.25156 0.0801977 "
      "-22.0262 0 0 0 1";
  const std::string referenceText =
      "0.949536 -0.208383 0.234431 264.096 -0.195717 -0.977686 -0.076326 93.8733 0.245105 0.0265923 -0.969132 "
      "3.0506 0 0 0 1";
  const std::string seq = dataFile("SpinePhantomFreehand.igs.mha");
  ASSERT_EQ(headerValue(seq, "Seq_Frame0000_ProbeToTrackerTransform"), probeText);
  ASSERT_EQ(headerValue(seq, "Seq_Frame0000_ReferenceToTrackerTransform"), referenceText);

  const Mat4 probeToTracker = parsed(probeText);
  const Mat4 referenceToTracker = parsed(referenceText);
  const Mat4 imageToProbe = cfg.coordinates.get("Image", "Probe").value();

  Frame frame;
  frame.setTransform("ProbeToTracker", probeToTracker);
  frame.setTransform("ReferenceToTracker", referenceToTracker);
  frame.setTransform("StylusToTracker", Mat4(1.0), /*valid=*/false);  // not on the chain
  const auto got = imageToReference(cfg, frame);
  ASSERT_TRUE(got);

  // By hand, with GLM's general inverse.
  const Mat4 byHand = glm::inverse(referenceToTracker) * probeToTracker * imageToProbe;
  expectNear(*got, byHand, 1e-9);
  // The first pixel lands where the chain puts the image origin.
  const Vec3 p0 = transformPoint(*got, Vec3(0, 0, 0));
  const Vec3 q0 = Vec3(byHand * Vec4(0, 0, 0, 1));
  EXPECT_LT(glm::length(p0 - q0), 1e-9);
  // The tracked transforms are rigid, so the frame's diagonal keeps the length
  // the calibration gives it (about 0.08 mm per pixel).
  const double diag = glm::length(transformPoint(*got, Vec3(820, 616, 0)) - p0);
  const double diagInProbe = glm::length(transformVector(imageToProbe, Vec3(820, 616, 0)));
  EXPECT_NEAR(diag, diagInProbe, 1e-4);  // the tracker prints 6 digits, so "rigid" to about 1e-6
  EXPECT_NEAR(diag, 83.36, 0.01);
}

TEST(PlusConfigData, ImageToReferenceNeedsValidPerFrameTransforms) {
  const auto cfg = readPlusConfig(dataFile("PlusDeviceSet_VolumeReconstructionOnly_SpinePhantom_NN_MEAN.xml"));
  Frame frame;
  frame.setTransform("ProbeToTracker", translation(Vec3(1, 2, 3)));
  EXPECT_FALSE(imageToReference(cfg, frame)) << "ReferenceToTracker missing";
  frame.setTransform("ReferenceToTracker", Mat4(1.0), /*valid=*/false);
  EXPECT_FALSE(imageToReference(cfg, frame)) << "ReferenceToTracker INVALID";
  frame.setTransform("ReferenceToTracker", Mat4(1.0), /*valid=*/true);
  const auto ok = imageToReference(cfg, frame);
  ASSERT_TRUE(ok);
  expectNear(*ok, translation(Vec3(1, 2, 3)) * cfg.coordinates.get("Image", "Probe").value(), 1e-12);
  frame.setTransform("ProbeToTracker", Mat4(1.0), /*valid=*/false);
  EXPECT_FALSE(imageToReference(cfg, frame)) << "ProbeToTracker INVALID";
}

// ---------------------------------------------------------------------------
// Errors

using PlusConfigErrors = TempDir;

TEST_F(PlusConfigErrors, NoChainFromImageToReference) {
  const std::string p = config("nochain.xml", "OutputSpacing=\"1 1 1\"");
  const auto cfg = readPlusConfig(p);
  const std::string msg = inputErrorOf([&] { cfg.planImageToReference({"ProbeToTracker"}); });
  EXPECT_THAT(msg, StartsWith(p + ": "));
  EXPECT_THAT(msg, HasSubstr("no chain from Image to Reference"));
  EXPECT_THAT(msg, HasSubstr("(ProbeToTracker)"));
  EXPECT_THAT(msg, HasSubstr("known frames: Image, Probe, Tracker"));
  // Named frames are used in the message and the search.
  const std::string q = config("named.xml", "OutputSpacing=\"1 1 1\" ImageCoordinateFrame=\"Image\" "
                                            "ReferenceCoordinateFrame=\"Phantom\"");
  const std::string msg2 = inputErrorOf([&] { readPlusConfig(q).planImageToReference({}); });
  EXPECT_THAT(msg2, HasSubstr("no chain from Image to Phantom"));
  EXPECT_THAT(msg2, HasSubstr("(none)"));
}

TEST_F(PlusConfigErrors, MalformedXmlNamesFileAndLine) {
  const std::string p = write("bad.xml",
                              "<PlusConfiguration version=\"2.1\">\n"
                              "  <CoordinateDefinitions>\n"
                              "    <Transform From=\"Image\" To=\"Probe\" Matrix=\"1 0 0 0\n"
                              "  </CoordinateDefinitions>\n"
                              "</PlusConfiguration>\n");
  const std::string msg = inputErrorOf([&] { readPlusConfig(p); });
  EXPECT_THAT(msg, StartsWith(p + ":"));
  EXPECT_THAT(msg, HasSubstr("malformed XML"));
  EXPECT_THAT(msg, HasSubstr("byte offset"));

  const std::string q = write("mismatch.xml", "<PlusConfiguration>\n  <A>\n  </B>\n</PlusConfiguration>\n");
  const std::string msg2 = inputErrorOf([&] { readPlusConfig(q); });
  EXPECT_THAT(msg2, StartsWith(q + ":3: malformed XML: "));
  EXPECT_THAT(msg2, HasSubstr("mismatch"));

  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(write("empty.xml", "")); }), HasSubstr("malformed XML"));
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(write("comment.xml", "<!-- only a comment -->")); }),
              HasSubstr("malformed XML"));
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(write("root.xml", "<Config/>")); }),
              HasSubstr("root element is <Config>, expected <PlusConfiguration>"));
  const std::string missing = path("does_not_exist.xml");
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(missing); }), StartsWith(missing + ": cannot open"));
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(dir_.string()); }), HasSubstr("cannot read: it is a folder, not a regular file"));
}

TEST_F(PlusConfigErrors, MatrixWithFifteenNumbers) {
  const std::string defs =
      "    <Transform From=\"Image\" To=\"Probe\"\n"
      "      Matrix=\"1 0 0 0  0 1 0 0  0 0 1 0  0 0 0\" />\n";
  const std::string p = config("m15.xml", "OutputSpacing=\"1 1 1\"", defs);
  const std::string msg = inputErrorOf([&] { readPlusConfig(p); });
  EXPECT_EQ(msg, p + ":3: CoordinateDefinitions: Transform ImageToProbe: Matrix has 15 numbers, expected 16");

  const std::string nan = config("mnan.xml", "OutputSpacing=\"1 1 1\"",
                                 "<Transform From=\"Image\" To=\"Probe\" Matrix=\"nan 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\"/>");
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(nan); }), HasSubstr("Matrix 'nan' is not a finite number"));
  const std::string noMatrix = config("mnone.xml", "OutputSpacing=\"1 1 1\"", "<Transform From=\"Image\" To=\"Probe\"/>");
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(noMatrix); }), HasSubstr("Transform ImageToProbe: Matrix is missing"));
  const std::string noTo = config("mnoto.xml", "OutputSpacing=\"1 1 1\"", "<Transform From=\"Image\" Matrix=\"1\"/>");
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(noTo); }), HasSubstr("Transform: To is missing"));
  const std::string self = config("mself.xml", "OutputSpacing=\"1 1 1\"",
                                  "<Transform From=\"Image\" To=\"Image\" Matrix=\"1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\"/>");
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(self); }), HasSubstr("From and To are the same frame"));
  const std::string twice =
      config("mtwice.xml", "OutputSpacing=\"1 1 1\"",
             kImageToProbe + "<Transform From=\"Probe\" To=\"Image\" Matrix=\"1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\"/>");
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(twice); }), HasSubstr("ProbeToImage: ImageToProbe is already defined"));
}

TEST_F(PlusConfigErrors, BadEnumValues) {
  const std::string p = config("enum.xml", "OutputSpacing=\"1 1 1\" Interpolation=\"CUBIC\"");
  EXPECT_EQ(inputErrorOf([&] { readPlusConfig(p); }),
            p + ":5: VolumeReconstruction: Interpolation 'CUBIC' is not one of NEAREST_NEIGHBOR, LINEAR");
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(config("c.xml", "OutputSpacing=\"1 1 1\" CompoundingMode=\"AVG\"")); }),
              HasSubstr("CompoundingMode 'AVG' is not one of MEAN, LATEST, MAXIMUM, IMPORTANCE_MASK"));
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(config("o.xml", "OutputSpacing=\"1 1 1\" Optimization=\"MAX\"")); }),
              HasSubstr("Optimization 'MAX' is not one of NONE, PARTIAL, FULL, OPENCL"));
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(config("f.xml", "OutputSpacing=\"1 1 1\" FillHoles=\"YES\"")); }),
              HasSubstr("FillHoles 'YES' is not one of ON, OFF"));
  EXPECT_THAT(inputErrorOf([&] {
                readPlusConfig(config("a.xml", "OutputSpacing=\"1 1 1\" EnableFanAnglesAutoDetect=\"1\""));
              }),
              HasSubstr("EnableFanAnglesAutoDetect '1' is not one of TRUE, FALSE"));
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(config("l.xml", "OutputSpacing=\"1 1 1\" Compounding=\"MAYBE\"")); }),
              HasSubstr("Compounding 'MAYBE' is not one of ON, OFF"));
  EXPECT_THAT(inputErrorOf([&] {
                readPlusConfig(config("h.xml", "OutputSpacing=\"1 1 1\" FillHoles=\"ON\"", kImageToProbe,
                                      "<HoleFilling><HoleFillingElement Type=\"BLUR\"/></HoleFilling>"));
              }),
              HasSubstr("HoleFillingElement #1: Type 'BLUR' is not one of GAUSSIAN, GAUSSIAN_ACCUMULATION, STICK, "
                        "NEAREST_NEIGHBOR, DISTANCE_WEIGHT_INVERSE"));
}

// A second element would be ignored without a word (a device set with two
// volume reconstructors): refused, naming both lines.
TEST_F(PlusConfigErrors, ASecondVolumeReconstructionIsRefused) {
  const std::string text = "<PlusConfiguration version=\"2.1\">\n  <CoordinateDefinitions>\n" + kImageToProbe +
                           "  </CoordinateDefinitions>\n  <VolumeReconstruction OutputSpacing=\"1 1 1\" />\n"
                           "  <DataCollection><Device Id=\"R\"><VolumeReconstruction OutputSpacing=\"0.5 0.5 0.5\" />"
                           "</Device></DataCollection>\n</PlusConfiguration>\n";
  const std::string path = write("two.xml", text);
  EXPECT_THAT(inputErrorOf([&] { readPlusConfig(path); }),
              HasSubstr("a second VolumeReconstruction element (the first is on line 5)"));
}

TEST_F(PlusConfigErrors, BadNumbersAndMissingRequiredAttributes) {
  auto err = [&](const std::string& recon, const std::string& children = "") {
    return inputErrorOf([&] { readPlusConfig(config("n.xml", recon, kImageToProbe, children)); });
  };
  EXPECT_THAT(err("Interpolation=\"LINEAR\""), HasSubstr("VolumeReconstruction: OutputSpacing is missing"));
  EXPECT_THAT(err("OutputSpacing=\"0.5 0.5\""), HasSubstr("OutputSpacing '0.5 0.5' has 2 numbers, expected 3"));
  EXPECT_THAT(err("OutputSpacing=\"0.5 abc 0.5\""), HasSubstr("OutputSpacing '0.5 abc 0.5': 'abc' is not a finite number"));
  EXPECT_THAT(err("OutputSpacing=\"0.5 0 0.5\""), HasSubstr("OutputSpacing '0.5 0 0.5' must be positive"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" OutputExtent=\"0 10 0 10 0\""), HasSubstr("has 5 numbers, expected 6"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" OutputExtent=\"0 10 0 10 0 1.5\""), HasSubstr("'1.5' is not an integer"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" OutputExtent=\"0 10 5 4 0 1\""), HasSubstr("axis y ends (4) before it starts (5)"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" ClipRectangleSize=\"-1 5\""), HasSubstr("must not be negative"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" SkipInterval=\"0\""), HasSubstr("SkipInterval '0' must be at least 1"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" NumberOfThreads=\"-2\""), HasSubstr("NumberOfThreads '-2' must be in 0 .. 1024"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" FanAnglesDeg=\"-200 45\""),
              HasSubstr("FanAnglesDeg '-200 45' must lie in -180 .. 180 degrees"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" FanRadiusStartPixel=\"400\" FanRadiusStopPixel=\"300\""),
              HasSubstr("FanRadiusStartPixel '400' lies beyond the fan's stop radius '300'"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" FanRadiusStartPixel=\"600\""),
              HasSubstr("FanRadiusStartPixel '600' lies beyond the fan's stop radius '500'"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" NumberOfThreads=\"100000\""),
              HasSubstr("NumberOfThreads '100000' must be in 0 .. 1024"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" ImageCoordinateFrame=\"\""), HasSubstr("ImageCoordinateFrame is empty"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" CompoundingMode=\"IMPORTANCE_MASK\""),
              HasSubstr("ImportanceMaskFilename is missing"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" FillHoles=\"ON\""),
              HasSubstr("FillHoles is ON but there is no HoleFilling element"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" FillHoles=\"ON\"",
                  "<HoleFilling><HoleFillingElement Type=\"STICK\" NumberOfSticksToUse=\"1\"/></HoleFilling>"),
              HasSubstr("HoleFillingElement #1: StickLengthLimit is missing (Type STICK needs it)"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" FillHoles=\"ON\"",
                  "<HoleFilling><HoleFillingElement Type=\"GAUSSIAN\" Size=\"3\" MinimumKnownVoxelsRatio=\"0.5\"/>"
                  "</HoleFilling>"),
              HasSubstr("Stdev is missing (Type GAUSSIAN needs it)"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" FillHoles=\"ON\"",
                  "<HoleFilling><HoleFillingElement Type=\"NEAREST_NEIGHBOR\" Size=\"4\" "
                  "MinimumKnownVoxelsRatio=\"0.5\"/></HoleFilling>"),
              HasSubstr("Size '4' must be a positive odd number"));
  EXPECT_THAT(err("OutputSpacing=\"1 1 1\" FillHoles=\"ON\"",
                  "<HoleFilling><HoleFillingElement Type=\"NEAREST_NEIGHBOR\" Size=\"3\" "
                  "MinimumKnownVoxelsRatio=\"1.5\"/></HoleFilling>"),
              HasSubstr("MinimumKnownVoxelsRatio '1.5' must lie in [0, 1]"));
}

// ---------------------------------------------------------------------------
// Legacy and alternative spellings PLUS accepts

using PlusConfigSpellings = TempDir;

TEST_F(PlusConfigSpellings, LegacyCompoundingAndCalculation) {
  auto mode = [&](const std::string& recon) {
    return readPlusConfig(config("s.xml", "OutputSpacing=\"1 1 1\" " + recon)).volumeReconstruction->compounding;
  };
  EXPECT_EQ(mode(""), PlusCompounding::Mean);
  EXPECT_EQ(mode("Compounding=\"ON\""), PlusCompounding::Mean);
  EXPECT_EQ(mode("Compounding=\"OFF\""), PlusCompounding::Latest);
  EXPECT_EQ(mode("Compounding=\"off\""), PlusCompounding::Latest);
  EXPECT_EQ(mode("Calculation=\"MAXIMUM\""), PlusCompounding::Maximum);
  EXPECT_EQ(mode("Calculation=\"MAXIMUM\" Compounding=\"OFF\""), PlusCompounding::Maximum);
  EXPECT_EQ(mode("Calculation=\"WEIGHTED_AVERAGE\" Compounding=\"OFF\""), PlusCompounding::Latest);
  // CompoundingMode wins over the deprecated attributes.
  EXPECT_EQ(mode("CompoundingMode=\"MEAN\" Compounding=\"OFF\""), PlusCompounding::Mean);
  EXPECT_EQ(mode("CompoundingMode=\"latest\""), PlusCompounding::Latest);
  EXPECT_EQ(mode("CompoundingMode=\"Importance_Mask\" ImportanceMaskFilename=\"mask.png\""),
            PlusCompounding::ImportanceMask);
  EXPECT_EQ(mode("CompoundingMode=\"IMPORTANCEMASK\" ImportanceMaskFilename=\"mask.png\""),
            PlusCompounding::ImportanceMask);
}

TEST_F(PlusConfigSpellings, DeprecatedFanAttributesAndOpenCl) {
  const auto v = readPlusConfig(config("fan.xml",
                                       "OutputSpacing=\"1 1 1\" FanAngles=\"-30 30\" FanOrigin=\"100 -5\" "
                                       "FanDepth=\"400\" Optimization=\"OpenCL\" EnableFanAnglesAutoDetect=\"true\" "
                                       "FanAnglesAutoDetectBrightnessThreshold=\"25.5\" "
                                       "FanAnglesAutoDetectFilterRadiusPixel=\"7\" PixelRejectionThreshold=\"3\" "
                                       "SkipInterval=\"2\""))
                     .volumeReconstruction.value();
  EXPECT_EQ(v.fanAnglesDeg, glm::dvec2(-30, 30));
  EXPECT_EQ(v.fanOriginPixel, glm::dvec2(100, -5));
  EXPECT_EQ(v.fanRadiusStopPixel, 400.0);
  EXPECT_FALSE(v.fanRadiusStartPixel);
  EXPECT_EQ(v.optimization, PlusOptimization::GpuAcceleratedOpenCL);
  EXPECT_TRUE(v.enableFanAnglesAutoDetect);
  EXPECT_EQ(v.fanAnglesAutoDetectBrightnessThreshold, 25.5);
  EXPECT_EQ(v.fanAnglesAutoDetectFilterRadiusPixel, 7);
  EXPECT_EQ(v.pixelRejectionThreshold, 3.0);
  EXPECT_EQ(v.skipInterval, 2);
  // The current spelling wins when both are present.
  const auto w = readPlusConfig(config("fan2.xml",
                                       "OutputSpacing=\"1 1 1\" FanAngles=\"-30 30\" FanAnglesDeg=\"-20 20\" "
                                       "FanDepth=\"400\" FanRadiusStopPixel=\"300\" "
                                       "Optimization=\"GPU_ACCELERATION_OPENCL\""))
                     .volumeReconstruction.value();
  EXPECT_EQ(w.fanAnglesDeg, glm::dvec2(-20, 20));
  EXPECT_EQ(w.fanRadiusStopPixel, 300.0);
  EXPECT_EQ(w.optimization, PlusOptimization::GpuAcceleratedOpenCL);
}

TEST_F(PlusConfigSpellings, PersistentTransformsAreRead) {
  const auto cfg = readPlusConfig(config(
      "persist.xml", "OutputSpacing=\"1 1 1\"",
      kImageToProbe + "<Transform From=\"Phantom\" To=\"Reference\" Persistent=\"FALSE\" "
                      "Matrix=\"1 0 0 7 0 1 0 0 0 0 1 0 0 0 0 1\" Error=\"0.5\" Date=\"2011.12.06\"/>"));
  EXPECT_EQ(cfg.coordinates.get("Reference", "Phantom").value()[3], Vec4(-7, 0, 0, 1));
}

TEST_F(PlusConfigSpellings, NoVolumeReconstructionElement) {
  const std::string p = write("none.xml",
                              "<PlusConfiguration>\n<CoordinateDefinitions>\n" + kImageToProbe +
                                  "</CoordinateDefinitions>\n</PlusConfiguration>\n");
  const auto cfg = readPlusConfig(p);
  EXPECT_FALSE(cfg.volumeReconstruction);
  EXPECT_EQ(cfg.imageFrame(), "Image");
  EXPECT_EQ(cfg.referenceFrame(), "Reference");
  const auto plan = cfg.planImageToReference({"ProbeToReference"});
  EXPECT_EQ(plan.frames, (std::vector<std::string>{"Image", "Probe", "Reference"}));
}

// ---------------------------------------------------------------------------
// Writing

using PlusConfigWrite = TempDir;

TEST_F(PlusConfigWrite, RoundTripsEveryField) {
  PlusVolumeReconstruction r;
  r.imageCoordinateFrame = "ImageFull";
  r.referenceCoordinateFrame = "Phantom";
  r.outputSpacing = Vec3(0.1, 1.0 / 3.0, 0.25);
  r.outputOrigin = Vec3(-10.125, -128.0 / 7.0, 1e-7);
  r.outputExtent = std::array<int, 6>{0, 20, -3, 15, 0, 12};
  r.clipRectangleOrigin = glm::ivec2(192, 16);
  r.clipRectangleSize = glm::ivec2(420, 580);
  r.fanAnglesDeg = glm::dvec2(-44.9, 45.1);
  r.fanOriginPixel = glm::dvec2(380.5, -20);
  r.fanRadiusStartPixel = 360.0 / 7.0;
  r.fanRadiusStopPixel = 120.25;
  r.enableFanAnglesAutoDetect = true;
  r.fanAnglesAutoDetectBrightnessThreshold = 12.75;
  r.fanAnglesAutoDetectFilterRadiusPixel = 4;
  r.skipInterval = 3;
  r.interpolation = PlusInterpolation::Linear;
  r.compounding = PlusCompounding::ImportanceMask;
  r.optimization = PlusOptimization::GpuAcceleratedOpenCL;
  r.numberOfThreads = 6;
  r.fillHoles = true;
  r.pixelRejectionThreshold = 0.5;
  r.importanceMaskFile = "masks/importance & weight.png";
  PlusHoleFillingElement g;
  g.type = PlusHoleFillingType::GaussianAccumulation;
  g.size = 5;
  g.stdev = 0.75;
  g.minRatio = 0.125;
  PlusHoleFillingElement s;
  s.type = PlusHoleFillingType::Stick;
  s.stickLengthLimit = 11;
  s.numberOfSticksToUse = 3;
  s.size = 7;  // unused by STICK but still kept
  PlusHoleFillingElement d;
  d.type = PlusHoleFillingType::DistanceWeightInverse;
  d.size = 9;
  d.minRatio = 0.0;
  r.holeFilling = {g, s, d};

  Mat4 awkward(1.0);
  awkward[0][0] = 0.1;
  awkward[1][0] = 1.0 / 3.0;
  awkward[3] = Vec4(-1e-300, 123456.789, 2.0 / 3.0, 1.0);
  const std::vector<PlusConfigTransform> transforms{
      {"Image", "ImageFull", translation(Vec3(335, 285, 0))},
      {"ImageFull", "Probe", awkward},
      {"Phantom", "Reference", rotationAxisAngle(Vec3(1, 2, 3), 0.7)},
  };
  const std::string p = path("written.xml");
  writePlusConfig(p, transforms, r, "round trip <&> \"test\"");

  const auto cfg = readPlusConfig(p);
  ASSERT_TRUE(cfg.volumeReconstruction);
  EXPECT_EQ(*cfg.volumeReconstruction, r);
  EXPECT_EQ(cfg.transforms, transforms);
  EXPECT_EQ(cfg.deviceSetDescription, "round trip <&> \"test\"");
  EXPECT_EQ(cfg.deviceSetName, "pp5echo");
  EXPECT_EQ(cfg.coordinates.get("ImageFull", "Probe"), awkward);
  EXPECT_FALSE(fs::exists(p + ".tmp"));

  // The chain of a written config is usable as is.
  EXPECT_EQ(cfg.planImageToReference({"ProbeToTracker", "ReferenceToTracker"}).frames,
            (std::vector<std::string>{"ImageFull", "Probe", "Tracker", "Reference", "Phantom"}));

  // The file is a PLUS 2.1 device set.
  std::ifstream in(p);
  std::stringstream text;
  text << in.rdbuf();
  EXPECT_THAT(text.str(), HasSubstr("<PlusConfiguration version=\"2.1\">"));
  EXPECT_THAT(text.str(), HasSubstr("<DeviceSet Name=\"pp5echo\""));
  EXPECT_THAT(text.str(), HasSubstr("Optimization=\"OPENCL\""));
  EXPECT_THAT(text.str(), HasSubstr("Matrix=\"1 0 0 335  0 1 0 285  0 0 1 0  0 0 0 1\""));
}

TEST_F(PlusConfigWrite, RoundTripsDefaults) {
  const PlusVolumeReconstruction r;
  const std::string p = path("defaults.xml");
  writePlusConfig(p, {}, r, "");
  const auto cfg = readPlusConfig(p);
  ASSERT_TRUE(cfg.volumeReconstruction);
  EXPECT_EQ(*cfg.volumeReconstruction, r);
  EXPECT_TRUE(cfg.transforms.empty());
}

TEST_F(PlusConfigWrite, RewritesADataConfigToTheSameSettings) {
  for (const auto& f : allConfigs()) {
    SCOPED_TRACE(f);
    const auto a = readPlusConfig(f);
    const std::string p = path("copy.xml");
    writePlusConfig(p, a.transforms, a.volumeReconstruction.value(), a.deviceSetDescription);
    const auto b = readPlusConfig(p);
    EXPECT_EQ(b.volumeReconstruction, a.volumeReconstruction);
    EXPECT_EQ(b.transforms, a.transforms);
  }
}

TEST_F(PlusConfigWrite, UnwritablePathIsAnInputErrorAndLeavesNothingBehind) {
  const std::string p = path("no/such/dir/out.xml");
  EXPECT_THAT(inputErrorOf([&] { writePlusConfig(p, {}, PlusVolumeReconstruction{}, "x"); }),
              StartsWith(p + ": cannot write"));
  // An existing config is replaced whole.
  const std::string q = path("existing.xml");
  writePlusConfig(q, {}, PlusVolumeReconstruction{}, "first");
  writePlusConfig(q, {}, PlusVolumeReconstruction{}, "second");
  EXPECT_EQ(readPlusConfig(q).deviceSetDescription, "second");
  EXPECT_FALSE(fs::exists(q + ".tmp"));
}

}  // namespace
}  // namespace pp5
