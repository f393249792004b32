// Rigid transforms, row-major text, the transform repository and PLUS transform names.
#include <cmath>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include "core/transform.hpp"

namespace pp5 {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Frame 0 of SpinePhantomFreehand.igs.mha, exactly as the header writes it.
const char* kProbeToTracker0 =
    "0.231245 0.951424 -0.203269 172.641 -0.127436 -0.17751 -0.975833 -98.0022 -0.964513 0.25156 0.0801977 "
    "-22.0262 0 0 0 1";

std::string readHeaderLine(const std::string& file, const std::string& key) {
  std::ifstream in(file, std::ios::binary);
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("ElementDataFile", 0) == 0) break;  // binary data follows
    if (line.rfind(key + " = ", 0) == 0) {
      std::string v = line.substr(key.size() + 3);
      while (!v.empty() && (v.back() == '\r' || v.back() == ' ')) v.pop_back();
      return v;
    }
  }
  return {};
}

void expectNear(const Mat4& a, const Mat4& b, double tol) {
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r) EXPECT_NEAR(a[c][r], b[c][r], tol) << "row " << r << " col " << c;
}

Mat4 randomAffine(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  std::uniform_real_distribution<double> t(-200.0, 200.0);
  Mat4 m(1.0);
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) m[c][r] = u(rng);
  m[3] = Vec4(t(rng), t(rng), t(rng), 1.0);
  return m;
}

Mat4 randomRigid(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::uniform_real_distribution<double> a(-kPi, kPi);
  std::uniform_real_distribution<double> t(-300.0, 300.0);
  Vec3 axis(u(rng), u(rng), u(rng));
  if (glm::length(axis) < 1e-3) axis = Vec3(0, 0, 1);
  return translation(Vec3(t(rng), t(rng), t(rng))) * rotationAxisAngle(axis, a(rng));
}

// ---- row-major text ----

TEST(RowMajor, ParsesAPlusHeaderLineIntoGlmLayout) {
  const std::string fromFile =
      readHeaderLine(std::string(PP5_DATA_DIR) + "/SpinePhantomFreehand.igs.mha", "Seq_Frame0000_ProbeToTrackerTransform");
  ASSERT_EQ(fromFile, kProbeToTracker0) << "the test's copy of the header line is out of date";

  std::string why;
  const auto m = parseRowMajor(fromFile, &why);
  ASSERT_TRUE(m) << why;
  // GLM is column-major: the translation column is m[3].
  EXPECT_EQ((*m)[3], Vec4(172.641, -98.0022, -22.0262, 1.0));
  // Row 1, column 0 of the text is m[0][1].
  EXPECT_EQ((*m)[0][1], -0.127436);
  EXPECT_EQ((*m)[1][0], 0.951424);
  EXPECT_EQ((*m)[2][2], 0.0801977);
  EXPECT_EQ(Vec4((*m)[0][3], (*m)[1][3], (*m)[2][3], (*m)[3][3]), Vec4(0, 0, 0, 1));
  // A point is moved by the translation.
  EXPECT_EQ(transformPoint(*m, Vec3(0.0)), Vec3(172.641, -98.0022, -22.0262));
  // The tracker reports a rotation, to its printed precision.
  EXPECT_TRUE(isRigid(*m, 1e-5));
}

TEST(RowMajor, FromAndToRowMajorAreInverse) {
  std::array<double, 16> v{};
  for (std::size_t i = 0; i < v.size(); ++i) v[i] = static_cast<double>(i) + 0.5;
  const Mat4 m = fromRowMajor(v);
  EXPECT_EQ(m[3][0], 3.5);   // row 0, column 3
  EXPECT_EQ(m[0][3], 12.5);  // row 3, column 0
  EXPECT_EQ(toRowMajor(m), v);
}

TEST(RowMajor, AcceptsAnyWhitespaceAndPlusSigns) {
  const auto m = parseRowMajor("\n  +1\t0 0 10\r\n 0 1 0 -8.23381e-005\n0 0 1 3  \n 0 0 0 1\n");
  ASSERT_TRUE(m);
  EXPECT_EQ((*m)[3], Vec4(10.0, -8.23381e-5, 3.0, 1.0));
}

TEST(RowMajor, RejectsWrongCountsAndNonNumbers) {
  std::string why;
  EXPECT_FALSE(parseRowMajor("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0", &why));
  EXPECT_EQ(why, "has 15 numbers, expected 16");
  EXPECT_FALSE(parseRowMajor("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1 7", &why));
  EXPECT_EQ(why, "has 17 numbers, expected 16");
  EXPECT_FALSE(parseRowMajor("", &why));
  EXPECT_EQ(why, "has 0 numbers, expected 16");
  EXPECT_FALSE(parseRowMajor("1 0 0 0 0 1 0 0 0 0 1 0 0 0 abc 1", &why));
  EXPECT_EQ(why, "'abc' is not a number");
  EXPECT_FALSE(parseRowMajor("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1.5x", &why));
  EXPECT_EQ(why, "'1.5x' is not a number");
  EXPECT_FALSE(parseRowMajor("1,0,0,0 0 1 0 0 0 0 1 0 0 0 0 1", &why));
  EXPECT_NE(why.find("is not a number"), std::string::npos);
  for (const char* bad : {"nan", "NaN", "inf", "-inf", "infinity"}) {
    const std::string text = std::string("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 ") + bad;
    EXPECT_FALSE(parseRowMajor(text, &why)) << bad;
    EXPECT_EQ(why, std::string("'") + bad + "' is not a finite number");
  }
  EXPECT_FALSE(parseRowMajor("1e999 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", &why));
  EXPECT_NE(why.find("'1e999'"), std::string::npos) << why;
  // `why` is optional.
  EXPECT_FALSE(parseRowMajor("1 2 3"));
}

TEST(RowMajor, FormatReadsBackExactly) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1e3, 1e3);
  for (int trial = 0; trial < 200; ++trial) {
    Mat4 m;
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r) m[c][r] = u(rng) / 3.0;
    m[0][0] = 0.1;
    m[1][1] = 1.0 / 3.0;
    m[2][2] = -1e-300;
    m[3][3] = 5e-324;  // smallest subnormal
    const auto back = parseRowMajor(formatRowMajor(m));
    ASSERT_TRUE(back);
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r) ASSERT_EQ((*back)[c][r], m[c][r]) << formatRowMajor(m);
  }
  EXPECT_EQ(formatRowMajor(Mat4(1.0)), "1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1");
}

// ---- matrix helpers ----

TEST(Matrix, IsFinite) {
  Mat4 m(1.0);
  EXPECT_TRUE(isFinite(m));
  m[2][1] = std::nan("");
  EXPECT_FALSE(isFinite(m));
  m[2][1] = -INFINITY;
  EXPECT_FALSE(isFinite(m));
}

TEST(Matrix, IsRigid) {
  std::mt19937 rng(3);
  for (int i = 0; i < 20; ++i) EXPECT_TRUE(isRigid(randomRigid(rng)));
  EXPECT_TRUE(isRigid(Mat4(1.0)));
  EXPECT_FALSE(isRigid(scaling(Vec3(0.085, 0.085, 0.085))));
  EXPECT_FALSE(isRigid(scaling(Vec3(1, 1, -1)))) << "a reflection is not a rigid motion";
  Mat4 projective(1.0);
  projective[2][3] = 0.1;  // last row (0 0 0.1 1)
  EXPECT_FALSE(isRigid(projective));
  Mat4 nearly = rotationAxisAngle(Vec3(1, 2, 3), 0.7);
  nearly[0][0] += 1e-8;
  EXPECT_TRUE(isRigid(nearly, 1e-6));
  EXPECT_FALSE(isRigid(nearly, 1e-10));
}

TEST(Matrix, AffineInverseMatchesGlmInverse) {
  std::mt19937 rng(11);
  for (int trial = 0; trial < 500; ++trial) {
    const Mat4 m = randomAffine(rng);
    if (std::abs(glm::determinant(glm::dmat3(m))) < 1e-2) continue;  // too close to singular to compare
    const Mat4 ours = affineInverse(m);
    const Mat4 ref = glm::inverse(m);
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r)
        ASSERT_NEAR(ours[c][r], ref[c][r], 1e-9 * (1.0 + std::abs(ref[c][r]))) << trial;
    // The last row stays exactly (0 0 0 1).
    EXPECT_EQ(Vec4(ours[0][3], ours[1][3], ours[2][3], ours[3][3]), Vec4(0, 0, 0, 1));
  }
}

TEST(Matrix, RigidRoundTrips) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 200; ++trial) {
    const Mat4 a = randomRigid(rng);
    const Mat4 b = randomRigid(rng);
    expectNear(affineInverse(a) * a, Mat4(1.0), 1e-12);
    expectNear(a * affineInverse(a), Mat4(1.0), 1e-12);
    expectNear(affineInverse(affineInverse(a)), a, 1e-12);
    expectNear(affineInverse(a * b), affineInverse(b) * affineInverse(a), 1e-11);
    const Vec3 p(12.5, -3.25, 80.0);
    const Vec3 back = transformPoint(affineInverse(a), transformPoint(a, p));
    EXPECT_NEAR(glm::length(back - p), 0.0, 1e-11);
    // Vectors ignore translation.
    EXPECT_NEAR(glm::length(transformVector(a, Vec3(0, 0, 1))), 1.0, 1e-12);
  }
}

TEST(Matrix, AffineInverseOfScaledCalibration) {
  // ImageToProbe includes mm per pixel, so it is affine but not rigid.
  const Mat4 m = translation(Vec3(15.3978, 49.5705, -8.63446)) * rotationAxisAngle(Vec3(0, 0, 1), 0.3) *
                 scaling(Vec3(0.085, 0.085, 0.085));
  expectNear(affineInverse(m) * m, Mat4(1.0), 1e-12);
  // Singular input: non-finite output, which callers catch with isFinite.
  EXPECT_FALSE(isFinite(affineInverse(scaling(Vec3(1, 0, 1)))));
}

TEST(Matrix, RotationAxisAngleKnownRotations) {
  const double q = kPi / 2;
  auto near = [](const Vec3& a, const Vec3& b) { return glm::length(a - b) < 1e-15; };
  EXPECT_TRUE(near(transformPoint(rotationAxisAngle(Vec3(0, 0, 1), q), Vec3(1, 0, 0)), Vec3(0, 1, 0)));
  EXPECT_TRUE(near(transformPoint(rotationAxisAngle(Vec3(1, 0, 0), q), Vec3(0, 1, 0)), Vec3(0, 0, 1)));
  EXPECT_TRUE(near(transformPoint(rotationAxisAngle(Vec3(0, 1, 0), q), Vec3(0, 0, 1)), Vec3(1, 0, 0)));
  // The axis need not be unit length; a negative angle turns the other way.
  EXPECT_TRUE(near(transformPoint(rotationAxisAngle(Vec3(0, 0, 5), -q), Vec3(1, 0, 0)), Vec3(0, -1, 0)));
  // 120 degrees about (1,1,1) cycles the axes x -> y -> z.
  const Mat4 cyc = rotationAxisAngle(Vec3(1, 1, 1), 2 * kPi / 3);
  EXPECT_LT(glm::length(transformPoint(cyc, Vec3(1, 0, 0)) - Vec3(0, 1, 0)), 1e-15);
  EXPECT_LT(glm::length(transformPoint(cyc, Vec3(0, 1, 0)) - Vec3(0, 0, 1)), 1e-15);
  // A zero axis gives no rotation rather than NaNs.
  EXPECT_EQ(rotationAxisAngle(Vec3(0.0), 1.0), Mat4(1.0));
  // Agrees with GLM's own rotate for arbitrary axes.
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < 50; ++i) {
    const Vec3 axis(u(rng), u(rng), u(rng));
    const double angle = 4 * u(rng);
    const Mat4 ours = rotationAxisAngle(axis, angle);
    expectNear(ours, glm::rotate(Mat4(1.0), angle, axis), 1e-14);
    EXPECT_TRUE(isRigid(ours, 1e-12));
    EXPECT_LT(glm::length(transformVector(ours, axis) - axis), 1e-14) << "the axis is fixed";
  }
}

TEST(Matrix, TranslationAndScaling) {
  EXPECT_EQ(transformPoint(translation(Vec3(1, 2, 3)), Vec3(10, 20, 30)), Vec3(11, 22, 33));
  EXPECT_EQ(transformVector(translation(Vec3(1, 2, 3)), Vec3(10, 20, 30)), Vec3(10, 20, 30));
  EXPECT_EQ(transformPoint(scaling(Vec3(2, 3, 4)), Vec3(1, 1, 1)), Vec3(2, 3, 4));
  EXPECT_EQ(translation(Vec3(1, 2, 3))[3], Vec4(1, 2, 3, 1));
}

TEST(Matrix, CalibrationChainComposes) {
  CalibrationChain c;
  c.imageToProbe = scaling(Vec3(0.1, 0.1, 0.1));
  c.probeToTracker = translation(Vec3(100, 0, 0));
  c.referenceToTracker = translation(Vec3(0, 50, 0));
  EXPECT_EQ(transformPoint(c.imageToReference(), Vec3(10, 20, 0)), Vec3(101, -48, 0));
}

// ---- repository ----

TEST(TransformRepository, DirectAndInverse) {
  TransformRepository repo;
  const Mat4 a = translation(Vec3(1, 2, 3)) * rotationAxisAngle(Vec3(0, 1, 0), 0.4);
  repo.set("Probe", "Tracker", a);
  EXPECT_EQ(repo.get("Probe", "Tracker"), a);
  const auto inv = repo.get("Tracker", "Probe");
  ASSERT_TRUE(inv);
  expectNear(*inv * a, Mat4(1.0), 1e-13);
  EXPECT_EQ(repo.get("Probe", "Probe"), Mat4(1.0));
  EXPECT_EQ(repo.path("Tracker", "Probe"), (std::vector<std::string>{"Tracker", "Probe"}));
}

TEST(TransformRepository, MultiHopChainMatchesHandComposition) {
  std::mt19937 rng(1);
  const Mat4 imageToProbe = randomRigid(rng) * scaling(Vec3(0.08, 0.085, 0.08));
  const Mat4 probeToTracker = randomRigid(rng);
  const Mat4 referenceToTracker = randomRigid(rng);
  const Mat4 phantomToReference = randomRigid(rng);
  TransformRepository repo;
  repo.set("Image", "Probe", imageToProbe);
  repo.set("Phantom", "Reference", phantomToReference);
  repo.set("Probe", "Tracker", probeToTracker);
  repo.set("Reference", "Tracker", referenceToTracker);

  EXPECT_EQ(repo.path("Image", "Reference"), (std::vector<std::string>{"Image", "Probe", "Tracker", "Reference"}));
  const auto got = repo.get("Image", "Reference");
  ASSERT_TRUE(got);
  expectNear(*got, glm::inverse(referenceToTracker) * probeToTracker * imageToProbe, 1e-10);
  CalibrationChain c{imageToProbe, probeToTracker, referenceToTracker};
  expectNear(*got, c.imageToReference(), 1e-12);

  // Four hops, two of them backwards.
  const auto imageToPhantom = repo.get("Image", "Phantom");
  ASSERT_TRUE(imageToPhantom);
  expectNear(*imageToPhantom, glm::inverse(phantomToReference) * glm::inverse(referenceToTracker) * probeToTracker * imageToProbe,
             1e-9);
  const auto phantomToImage = repo.get("Phantom", "Image");
  ASSERT_TRUE(phantomToImage);
  expectNear(*phantomToImage * *imageToPhantom, Mat4(1.0), 1e-10);

  EXPECT_EQ(repo.frames(), (std::vector<std::string>{"Image", "Probe", "Phantom", "Reference", "Tracker"}));
}

TEST(TransformRepository, MissingChain) {
  TransformRepository repo;
  repo.set("Image", "Probe", Mat4(1.0));
  repo.set("Reference", "Tracker", Mat4(1.0));
  EXPECT_FALSE(repo.get("Image", "Reference"));
  EXPECT_TRUE(repo.path("Image", "Reference").empty());
  EXPECT_FALSE(repo.get("Image", "Nowhere"));
  EXPECT_FALSE(repo.get("Nowhere", "Image"));
  EXPECT_FALSE(TransformRepository().get("A", "B"));
  EXPECT_TRUE(TransformRepository().frames().empty());
}

TEST(TransformRepository, InvalidEdgeOnTheChain) {
  TransformRepository repo;
  repo.set("Image", "Probe", scaling(Vec3(0.1)));
  repo.set("Probe", "Tracker", translation(Vec3(1, 0, 0)), /*valid=*/false);
  repo.set("Reference", "Tracker", translation(Vec3(0, 1, 0)));
  repo.set("Stylus", "Tracker", Mat4(1.0), /*valid=*/false);
  EXPECT_FALSE(repo.get("Image", "Reference"));
  EXPECT_FALSE(repo.get("Tracker", "Probe")) << "the inverse of an invalid edge is invalid too";
  // The path still exists; only its value is unusable.
  EXPECT_EQ(repo.path("Image", "Reference").size(), 4u);
  // An invalid edge elsewhere does not matter.
  EXPECT_TRUE(repo.get("Reference", "Tracker"));
  // Once the tracker reports the probe again, the chain works.
  repo.set("Probe", "Tracker", translation(Vec3(1, 0, 0)), true);
  EXPECT_TRUE(repo.get("Image", "Reference"));
}

TEST(TransformRepository, ReplacingKeepsOneEdgePerPair) {
  TransformRepository repo;
  repo.set("A", "B", translation(Vec3(1, 0, 0)));
  repo.set("A", "B", translation(Vec3(2, 0, 0)));
  EXPECT_EQ(repo.get("A", "B"), translation(Vec3(2, 0, 0)));
  // Setting the other direction replaces the edge, so both directions agree.
  repo.set("B", "A", translation(Vec3(5, 0, 0)));
  EXPECT_EQ(repo.get("B", "A"), translation(Vec3(5, 0, 0)));
  EXPECT_EQ(repo.get("A", "B"), translation(Vec3(-5, 0, 0)));
  EXPECT_EQ(repo.frames().size(), 2u);
}

TEST(TransformRepository, PrefersTheShortestChain) {
  TransformRepository repo;
  repo.set("A", "B", translation(Vec3(1, 0, 0)));
  repo.set("B", "C", translation(Vec3(1, 0, 0)));
  repo.set("C", "D", translation(Vec3(1, 0, 0)));
  repo.set("D", "E", translation(Vec3(1, 0, 0)));
  repo.set("A", "E", translation(Vec3(10, 0, 0)));
  EXPECT_EQ(repo.path("A", "E"), (std::vector<std::string>{"A", "E"}));
  EXPECT_EQ(repo.get("A", "E"), translation(Vec3(10, 0, 0)));
  // B..E: back through A (2 links) rather than on through C and D (3 links).
  EXPECT_EQ(repo.path("B", "E"), (std::vector<std::string>{"B", "A", "E"}));
  EXPECT_EQ(repo.get("B", "E"), translation(Vec3(9, 0, 0)));
}

TEST(TransformRepository, RejectsDegenerateNames) {
  TransformRepository repo;
  EXPECT_ANY_THROW(repo.set("A", "A", Mat4(1.0)));
  EXPECT_ANY_THROW(repo.set("", "A", Mat4(1.0)));
}

// ---- names ----

TEST(TransformName, Splits) {
  using P = std::pair<std::string, std::string>;
  EXPECT_EQ(splitTransformName("ProbeToTracker"), P("Probe", "Tracker"));
  EXPECT_EQ(splitTransformName("StylusTipToReference"), P("StylusTip", "Reference"));
  EXPECT_EQ(splitTransformName("ImageFullToProbe"), P("ImageFull", "Probe"));
  EXPECT_EQ(splitTransformName("ImageToCroppedImage"), P("Image", "CroppedImage"));
  // "To" inside a frame name is not followed by an uppercase letter.
  EXPECT_EQ(splitTransformName("ToolToReference"), P("Tool", "Reference"));
  EXPECT_EQ(splitTransformName("TestToolToTracker"), P("TestTool", "Tracker"));
  EXPECT_EQ(splitTransformName("TransducerOriginPixelToTransducerOrigin"), P("TransducerOriginPixel", "TransducerOrigin"));
  // A "To" at the very start cannot end a From name.
  EXPECT_EQ(splitTransformName("ToXToY"), P("ToX", "Y"));
  // Unambiguous but lowercase: accepted as written.
  EXPECT_EQ(splitTransformName("probeToTracker"), P("probe", "Tracker"));
}

TEST(TransformName, RejectsNamesWithoutOneClearSplit) {
  EXPECT_FALSE(splitTransformName(""));
  EXPECT_FALSE(splitTransformName("Probe"));
  EXPECT_FALSE(splitTransformName("ProbeTo"));
  EXPECT_FALSE(splitTransformName("ToProbe"));
  EXPECT_FALSE(splitTransformName("Probetotracker"));
  EXPECT_FALSE(splitTransformName("ProbeTotracker"));
  // Ambiguous: Image -> TorsoToReference or ImageToTorso -> Reference. PLUS refuses it too.
  EXPECT_FALSE(splitTransformName("ImageToTorsoToReference"));
}

}  // namespace
}  // namespace pp5
