// Volume reading and writing, PLUS's reference volumes, and `pp5echo info`.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <nlohmann/json.hpp>
#include <random>

#include "core/error.hpp"
#include "formats/volume_io.hpp"
#include "io_test_util.hpp"

namespace pp5 {
namespace {

using test::TempDir;

const char* const kReferenceVolumes[] = {
    "vtkVolumeReconstructorTestNNMEANvolumeRef.mha", "vtkVolumeReconstructorTestNNLATEvolumeRef.mha",
    "vtkVolumeReconstructorTestLNMEANvolumeRef.mha", "vtkVolumeReconstructorTestLNMAXIvolumeRef.mha",
    "SpinePhantomFreehandReconstructed.mha",         "vtkVolumeReconstructorMaximum1OutputCompare.mha",
    "NwirePhantomFreehandReconstructed.mha",
};

// Dims, spacing and origin as the header text gives them, parsed with strtod.
struct HeaderGeometry {
  std::vector<double> dims, spacing, origin;
};

HeaderGeometry geometryOf(const std::string& header) {
  return {test::numbers(test::headerValue(header, "DimSize")),
          test::numbers(test::headerValue(header, "ElementSpacing")),
          test::numbers(test::headerValue(header, "Offset"))};
}

void expectGridIs(const Grid& g, const HeaderGeometry& h) {
  ASSERT_EQ(h.dims.size(), 3u);
  ASSERT_EQ(h.spacing.size(), 3u);
  ASSERT_EQ(h.origin.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(static_cast<double>(g.dims[i]), h.dims[static_cast<std::size_t>(i)]) << "axis " << i;
    EXPECT_EQ(g.spacing[i], h.spacing[static_cast<std::size_t>(i)]) << "axis " << i;
    EXPECT_EQ(g.origin[i], h.origin[static_cast<std::size_t>(i)]) << "axis " << i;
  }
}

TEST(VolumeIo, ReferenceVolumeHeadersGiveTheirDimsSpacingAndOrigin) {
  for (const char* name : kReferenceVolumes) {
    SCOPED_TRACE(name);
    const std::string path = test::dataFile(name);
    const test::RawFile raw = test::splitFile(path);
    const VolumeHeader h = readVolumeHeader(path);
    expectGridIs(h.grid, geometryOf(raw.header()));
    EXPECT_EQ(h.type, ScalarType::U8);
    EXPECT_EQ(h.channels, 1);
    EXPECT_EQ(h.compressed, test::headerValue(raw.header(), "CompressedData") == "True");
  }
}

TEST(VolumeIo, ReferenceVolumesReadWithTheSameVoxelsAsAnIndependentDecoding) {
  for (const char* name : kReferenceVolumes) {
    SCOPED_TRACE(name);
    const std::string path = test::dataFile(name);
    const test::RawFile raw = test::splitFile(path);
    const Volume v = readVolume(path);
    const std::size_t voxels = static_cast<std::size_t>(v.grid.voxelCount());
    ASSERT_EQ(v.bytes.size(), voxels);
    std::string expected = raw.data();
    if (v.grid.dims.x > 0 && test::headerValue(raw.header(), "CompressedData") == "True")
      expected = test::inflateAll(
          expected.substr(0, std::stoull(test::headerValue(raw.header(), "CompressedDataSize"))), voxels);
    ASSERT_EQ(expected.size(), voxels);
    EXPECT_EQ(0, std::memcmp(v.bytes.data(), expected.data(), voxels));
    // A reconstruction is not empty.
    std::size_t nonzero = 0;
    for (std::size_t i = 0; i < voxels; ++i) nonzero += v.value(i) > 0.0;
    EXPECT_GT(nonzero, voxels / 100);
  }
}

Volume makeVolume(ScalarType type) {
  Grid g;
  g.dims = Index3(5, 4, 3);
  g.spacing = Vec3(0.5, 0.25, 1.5);
  g.origin = Vec3(-74.5217, 165.573, 1.0 / 3.0);
  Volume v;
  v.allocate(g, type);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> d(0.0, 70000.0);
  for (std::size_t i = 0; i < g.voxelCount(); ++i) v.setValue(i, type == ScalarType::F32 ? d(rng) - 1000.5 : d(rng));
  return v;
}

TEST(VolumeIo, WriteReadRoundTripKeepsGridTypeAndValues) {
  for (ScalarType type : {ScalarType::U8, ScalarType::U16, ScalarType::F32}) {
    const Volume v = makeVolume(type);
    for (const char* name : {"v.mha", "v.mhd", "v.nrrd"}) {
      for (bool compress : {false, true}) {
        SCOPED_TRACE(std::string(name) + " " + scalarName(type) + (compress ? " compressed" : " raw"));
        TempDir dir;
        writeVolume(dir / name, v, compress);
        const VolumeHeader h = readVolumeHeader(dir / name);
        EXPECT_EQ(h.type, type);
        EXPECT_EQ(h.compressed, compress);
        const Volume back = readVolume(dir / name);
        EXPECT_EQ(back.type, type);
        EXPECT_EQ(back.grid.dims, v.grid.dims);
        EXPECT_EQ(back.grid.spacing, v.grid.spacing);
        EXPECT_EQ(back.grid.origin, v.grid.origin);
        EXPECT_EQ(back.bytes, v.bytes);
      }
    }
  }
}

TEST(VolumeIo, WrittenHeadersPlaceTheVolumeForSlicerItkAndVtk) {
  TempDir dir;
  const Volume v = makeVolume(ScalarType::U8);
  writeVolume(dir / "v.mha", v, false);
  const std::string mha = test::splitFile(dir / "v.mha").header();
  EXPECT_EQ(test::headerValue(mha, "DimSize"), "5 4 3");
  EXPECT_EQ(test::headerValue(mha, "ElementSpacing"), "0.5 0.25 1.5");
  EXPECT_EQ(test::numbers(test::headerValue(mha, "Offset")), (std::vector<double>{-74.5217, 165.573, 1.0 / 3.0}));
  EXPECT_EQ(test::headerValue(mha, "TransformMatrix"), "1 0 0 0 1 0 0 0 1");
  EXPECT_EQ(test::headerValue(mha, "AnatomicalOrientation"), "RAI");
  EXPECT_EQ(test::headerValue(mha, "ElementType"), "MET_UCHAR");
  EXPECT_EQ(test::splitFile(dir / "v.mha").data().size(), 60u);

  writeVolume(dir / "v.nrrd", v, true);
  const std::string nrrd = test::splitFile(dir / "v.nrrd").header();
  EXPECT_EQ(test::headerValue(nrrd, "space"), "left-posterior-superior");
  EXPECT_EQ(test::headerValue(nrrd, "space directions"), "(0.5,0,0) (0,0.25,0) (0,0,1.5)");
  EXPECT_EQ(test::numbers(test::headerValue(nrrd, "space origin")),
            (std::vector<double>{-74.5217, 165.573, 1.0 / 3.0}));
  EXPECT_EQ(test::headerValue(nrrd, "kinds"), "domain domain domain");
}

TEST(VolumeIo, NrrdInRasSpaceIsConvertedToTheMetaIoCoordinates) {
  TempDir dir;
  std::string text =
      "NRRD0004\ntype: uint8\ndimension: 3\nspace: right-anterior-superior\nsizes: 2 1 1\n"
      "space directions: (-0.5,0,0) (0,-0.5,0) (0,0,2)\nkinds: domain domain domain\nencoding: raw\n"
      "space origin: (10,20,30)\n\n";
  text += std::string("\x07\x09", 2);
  test::writeBytes(dir / "ras.nrrd", text);
  const Volume v = readVolume(dir / "ras.nrrd");
  EXPECT_EQ(v.grid.origin, Vec3(-10, -20, 30));
  EXPECT_EQ(v.grid.spacing, Vec3(0.5, 0.5, 2));
  EXPECT_EQ(v.value(1), 9.0);

  std::string rotated = text;
  rotated.replace(rotated.find("(0,-0.5,0)"), 10, "(0.5,-0.5,0)");
  test::writeBytes(dir / "rot.nrrd", rotated);
  EXPECT_THROW(readVolumeHeader(dir / "rot.nrrd"), InputError);
}

TEST(VolumeIo, ValuesClampAndRoundForIntegerTypes) {
  Grid g;
  g.dims = Index3(4, 1, 1);
  Volume v;
  v.allocate(g, ScalarType::U8);
  v.setValue(0, -5.0);
  v.setValue(1, 300.0);
  v.setValue(2, 2.5);
  v.setValue(3, NAN);
  EXPECT_EQ(v.value(0), 0.0);
  EXPECT_EQ(v.value(1), 255.0);
  EXPECT_EQ(v.value(2), 3.0);
  EXPECT_EQ(v.value(3), 0.0);
  v.allocate(g, ScalarType::U16);
  v.setValue(0, 65535.4);
  v.setValue(1, 70000.0);
  EXPECT_EQ(v.value(0), 65535.0);
  EXPECT_EQ(v.value(1), 65535.0);
  EXPECT_EQ(v.bytes[0], 0xff);
  v.allocate(g, ScalarType::F32);
  v.setValue(2, -1.25);
  EXPECT_EQ(v.value(2), -1.25);
  EXPECT_EQ(scalarBytes(ScalarType::F32), 4);
  EXPECT_STREQ(scalarName(ScalarType::U16), "uint16");
}

// The float-to-uint8 conversion (volume.mha as uint8, the OpenIGTLink
// volume) rounds as std::round does, halves away from zero, every float
// next to a half and at the ends included.
TEST(VolumeIo, FloatVoxelsToUint8RoundAsStdRound) {
  std::vector<float> xs = {0.0f, -0.0f, -1.0f, 0.5f, 1.5f, 2.5f, 254.5f, 255.0f, 256.0f, 1e30f, -1e30f,
                           NAN, INFINITY, -INFINITY, 1e-40f};
  for (int k = 0; k <= 255; ++k) {
    const float half = static_cast<float>(k) + 0.5f;
    xs.push_back(half);
    xs.push_back(std::nextafter(half, 0.0f));
    xs.push_back(std::nextafter(half, 1000.0f));
  }
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> any(-10.0f, 300.0f);
  for (int i = 0; i < 10000; ++i) xs.push_back(any(rng));
  Grid g;
  g.dims = Index3(static_cast<std::int64_t>(xs.size()), 1, 1);
  Volume v;
  v.allocate(g, ScalarType::F32);
  for (std::size_t i = 0; i < xs.size(); ++i) std::memcpy(v.bytes.data() + 4 * i, &xs[i], 4);
  std::vector<std::uint8_t> out(xs.size());
  v.toU8(0, xs.size(), out.data());
  for (std::size_t i = 0; i < xs.size(); ++i) {
    const double x = xs[i];
    const double want = !(x > 0.0) ? 0.0 : x >= 255.0 ? 255.0 : std::round(x);
    EXPECT_EQ(out[i], static_cast<std::uint8_t>(want)) << "voxel " << i << " = " << xs[i];
  }
  EXPECT_EQ(v.as(ScalarType::U8).bytes, out);
}

// ------------------------------------------------------------ pp5echo info

nlohmann::json info(const std::string& path) {
  const test::CommandResult r = test::runCommand(std::string("'") + PP5_BINARY + "' info '" + path + "'");
  EXPECT_EQ(r.exitCode, 0) << r.err;
  EXPECT_EQ(r.err, "");
  return nlohmann::json::parse(r.out);
}

TEST(InfoCommand, ReferenceVolumesShowTheirHeaderGeometry) {
  for (const char* name : kReferenceVolumes) {
    SCOPED_TRACE(name);
    const std::string path = test::dataFile(name);
    const HeaderGeometry expected = geometryOf(test::splitFile(path).header());
    const nlohmann::json j = info(path);
    EXPECT_EQ(j["kind"], "volume");
    EXPECT_EQ(j["format"], "metaio");
    EXPECT_EQ(j["scalar_type"], "uint8");
    EXPECT_EQ(j["dims"].get<std::vector<double>>(), expected.dims);
    EXPECT_EQ(j["spacing"].get<std::vector<double>>(), expected.spacing);
    EXPECT_EQ(j["origin"].get<std::vector<double>>(), expected.origin);
    EXPECT_EQ(j["memory_bytes"].get<double>(), expected.dims[0] * expected.dims[1] * expected.dims[2]);
  }
}

TEST(InfoCommand, SequencesAreSummarisedFrameByFrame) {
  const nlohmann::json j = info(test::dataFile("NwirePhantomFreehandCropped.igs.mha"));
  EXPECT_EQ(j["kind"], "sequence");
  EXPECT_EQ(j["format"], "metaio");
  EXPECT_EQ(j["frame_count"], 20);
  EXPECT_EQ(j["image_size"], nlohmann::json::array({200, 150}));
  EXPECT_EQ(j["pixel_type"], "uint8");
  EXPECT_EQ(j["orientation"], "MFA");
  EXPECT_EQ(j["compressed"], true);
  EXPECT_EQ(j["valid_image_frames"], 20);
  EXPECT_EQ(j["fields"]["UltrasoundImageType"], "BRIGHTNESS");
  for (const char* t : {"ImageToCroppedImage", "ProbeToTracker", "ReferenceToTracker", "StylusToTracker"})
    EXPECT_EQ(j["transforms"][t]["frames"], 20) << t;
  EXPECT_EQ(j["transforms"]["StylusToTracker"]["valid_frames"], 0);

  const std::string header = test::splitFile(test::dataFile("NwirePhantomFreehandCropped.igs.mha")).header();
  EXPECT_EQ(j["transforms"]["ProbeToTracker"]["valid_frames"].get<int>(), [&] {
    int ok = 0;
    for (int i = 0; i < 20; ++i) {
      char key[64];
      std::snprintf(key, sizeof key, "Seq_Frame%04d_ProbeToTrackerTransformStatus", i);
      ok += test::headerValue(header, key) == "OK";
    }
    return ok;
  }());
  const double first = std::strtod(test::headerValue(header, "Seq_Frame0000_Timestamp").c_str(), nullptr);
  const double last = std::strtod(test::headerValue(header, "Seq_Frame0019_Timestamp").c_str(), nullptr);
  EXPECT_EQ(j["time"]["first"].get<double>(), first);
  EXPECT_EQ(j["time"]["last"].get<double>(), last);
  EXPECT_DOUBLE_EQ(j["time"]["duration"].get<double>(), last - first);

  const nlohmann::json n = info(test::dataFile("NwirePhantomFreehand.igs.nrrd"));
  EXPECT_EQ(n["format"], "nrrd");
  EXPECT_EQ(n["frame_count"], 97);
  EXPECT_EQ(n["valid_image_frames"], 97);
}

TEST(InfoCommand, WrittenNrrdVolumeIsDescribed) {
  TempDir dir;
  const Volume v = makeVolume(ScalarType::F32);
  writeVolume(dir / "v.nrrd", v, true);
  const nlohmann::json j = info(dir / "v.nrrd");
  EXPECT_EQ(j["kind"], "volume");
  EXPECT_EQ(j["format"], "nrrd");
  EXPECT_EQ(j["scalar_type"], "float32");
  EXPECT_EQ(j["dims"], nlohmann::json::array({5, 4, 3}));
  EXPECT_EQ(j["origin"][2].get<double>(), 1.0 / 3.0);
  EXPECT_EQ(j["memory_bytes"], 5 * 4 * 3 * 4);
}

}  // namespace
}  // namespace pp5
