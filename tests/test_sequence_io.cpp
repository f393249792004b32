// PLUS sequence reading and writing, checked against the real PLUS recordings
// (decoded here independently with zlib and string parsing) and by round trips.
#include <gtest/gtest.h>

#include <cstring>
#include <random>

#include "core/error.hpp"
#include "formats/recording_journal.hpp"
#include "formats/sequence_io.hpp"
#include "io_test_util.hpp"

namespace pp5 {
namespace {

using test::TempDir;

struct PlusSequence {
  const char* name;
  std::uint64_t frames;
  int width;
  int height;
};

const PlusSequence kSequences[] = {
    {"SpinePhantomFreehand.igs.mha", 21, 820, 616},
    {"NwirePhantomFreehand.igs.mha", 97, 820, 616},
    {"NwirePhantomFreehand.igs.nrrd", 97, 820, 616},
    {"NwirePhantomFreehandCropped.igs.mha", 20, 200, 150},
    {"BoneUltrasound_L14.igs.mha", 21, 820, 616},
    {"fCal_Test_Calibration_3NWires_fCal2.0.igs.mha", 190, 820, 616},
    {"fCal_Test_Calibration_3NWires.igs.mha", 188, 820, 616},
};

std::string frameKey(std::uint64_t i, const std::string& rest) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "Seq_Frame%04llu_", static_cast<unsigned long long>(i));
  return buf + rest;
}

// Every transform of frame i in the header text equals what the reader returned, bit for bit.
void expectTransformsMatchHeader(const std::string& header, const Frame& f) {
  ASSERT_FALSE(f.transforms.empty());
  for (const auto& t : f.transforms) {
    const std::string text = test::headerValue(header, frameKey(f.index, t.name + "Transform"));
    ASSERT_FALSE(text.empty()) << t.name;
    const std::vector<double> expected = test::numbers(text);
    ASSERT_EQ(expected.size(), 16u);
    const auto got = toRowMajor(t.matrix);
    for (int k = 0; k < 16; ++k) EXPECT_EQ(got[k], expected[k]) << t.name << " element " << k;
    EXPECT_EQ(t.valid, test::headerValue(header, frameKey(f.index, t.name + "TransformStatus")) == "OK");
  }
}

TEST(SequenceIo, EveryPlusSequenceReadsAndMatchesAnIndependentDecoding) {
  for (const auto& s : kSequences) {
    SCOPED_TRACE(s.name);
    const std::string path = test::dataFile(s.name);
    const test::RawFile raw = test::splitFile(path);
    const std::string header = raw.header();
    const std::size_t frameBytes = static_cast<std::size_t>(s.width) * static_cast<std::size_t>(s.height);
    // All these files are compressed; MetaIO says how much, NRRD runs to the end.
    std::string blob = raw.data();
    const std::string compressedSize = test::headerValue(header, "CompressedDataSize");
    if (!compressedSize.empty()) blob.resize(std::stoull(compressedSize));
    const std::string pixels = test::inflateAll(blob, frameBytes * s.frames);
    ASSERT_EQ(pixels.size(), frameBytes * s.frames);

    auto reader = SequenceReader::open(path);
    const SequenceInfo& info = reader->info();
    EXPECT_EQ(info.frameCount, s.frames);
    EXPECT_EQ(info.width, s.width);
    EXPECT_EQ(info.height, s.height);
    EXPECT_EQ(info.pixelType, PixelType::U8);
    EXPECT_TRUE(info.compressed);
    EXPECT_EQ(info.orientation.substr(0, 2), "MF");  // no flip: pixels compare as stored

    Frame f;
    std::uint64_t n = 0;
    const std::uint64_t middle = s.frames / 2;
    while (reader->next(f)) {
      ASSERT_EQ(f.index, n);
      ASSERT_EQ(f.width, s.width);
      ASSERT_EQ(f.height, s.height);
      ASSERT_EQ(f.pixels.size(), frameBytes);
      const double ts = std::strtod(test::headerValue(header, frameKey(n, "Timestamp")).c_str(), nullptr);
      EXPECT_EQ(f.timestamp, ts) << "frame " << n;
      if (n == 0 || n == middle || n + 1 == s.frames) {
        EXPECT_EQ(0, std::memcmp(f.pixels.data(), pixels.data() + n * frameBytes, frameBytes)) << "frame " << n;
        expectTransformsMatchHeader(header, f);
      }
      ++n;
    }
    EXPECT_EQ(n, s.frames);
  }
}

TEST(SequenceIo, SpinePhantomFirstProbeTransformIsExactlyTheHeaderText) {
  const std::string path = test::dataFile("SpinePhantomFreehand.igs.mha");
  const std::string header = test::splitFile(path).header();
  const auto expected = test::numbers(test::headerValue(header, "Seq_Frame0000_ProbeToTrackerTransform"));
  ASSERT_EQ(expected.size(), 16u);
  auto reader = SequenceReader::open(path);
  Frame f;
  ASSERT_TRUE(reader->next(f));
  const FrameTransform* t = f.findTransform("ProbeToTracker");
  ASSERT_NE(t, nullptr);
  EXPECT_TRUE(t->valid);
  const auto got = toRowMajor(t->matrix);
  for (int k = 0; k < 16; ++k) EXPECT_EQ(got[k], expected[k]) << k;
  EXPECT_EQ(test::headerValue(header, "Seq_Frame0000_ImageStatus"), "OK");
  EXPECT_TRUE(f.imageValid);
  ASSERT_EQ(f.transforms.size(), 3u);
  EXPECT_EQ(f.transforms[0].name, "ProbeToTracker");
  EXPECT_EQ(f.transforms[1].name, "ReferenceToTracker");
  EXPECT_EQ(f.transforms[2].name, "StylusToTracker");
}

TEST(SequenceIo, NwireMhaAndNrrdHoldTheSameFrames) {
  auto mha = SequenceReader::open(test::dataFile("NwirePhantomFreehand.igs.mha"));
  auto nrrd = SequenceReader::open(test::dataFile("NwirePhantomFreehand.igs.nrrd"));
  EXPECT_EQ(mha->info().format, SequenceFormat::MetaIO);
  EXPECT_EQ(nrrd->info().format, SequenceFormat::Nrrd);
  EXPECT_EQ(mha->info().orientation, nrrd->info().orientation);
  Frame a, b;
  std::uint64_t n = 0;
  while (mha->next(a)) {
    ASSERT_TRUE(nrrd->next(b));
    SCOPED_TRACE("frame " + std::to_string(n));
    EXPECT_EQ(a.pixels, b.pixels);
    EXPECT_EQ(a.timestamp, b.timestamp);
    EXPECT_EQ(a.imageValid, b.imageValid);
    ASSERT_EQ(a.transforms.size(), 3u);
    ASSERT_EQ(a.transforms.size(), b.transforms.size());
    for (std::size_t i = 0; i < a.transforms.size(); ++i) {
      EXPECT_EQ(a.transforms[i].name, b.transforms[i].name);
      EXPECT_EQ(a.transforms[i].valid, b.transforms[i].valid);
      EXPECT_TRUE(a.transforms[i].matrix == b.transforms[i].matrix);
    }
    EXPECT_EQ(a.customFields, b.customFields);
    ++n;
  }
  EXPECT_FALSE(nrrd->next(b));
  EXPECT_EQ(n, 97u);
}

// ------------------------------------------------------------ round trips

Mat4 randomMatrix(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> d(-2000.0, 2000.0);
  std::array<double, 16> v{};
  for (auto& x : v) x = d(rng);
  v[1] = 0.1;      // not exact in binary
  v[2] = 1.0 / 3;  // needs all 17 digits
  v[3] = 1e-300;
  v[12] = v[13] = v[14] = 0.0;
  v[15] = 1.0;
  return fromRowMajor(v);
}

std::vector<Frame> makeFrames(PixelType type, int width, int height, int count) {
  std::mt19937_64 rng(42 + static_cast<int>(type));
  std::vector<Frame> frames;
  for (int i = 0; i < count; ++i) {
    Frame f;
    f.allocate(width, height, type);
    for (auto& p : f.pixels) p = static_cast<std::uint8_t>(rng());
    f.index = static_cast<std::uint64_t>(i);
    f.timestamp = 1234.5 + i * 0.033333333333333333;
    f.imageValid = i != 2;
    f.setTransform("ProbeToTracker", randomMatrix(rng), i != 1);
    f.setTransform("ReferenceToTracker", randomMatrix(rng), true);
    f.customFields = {{"FrameNumber", std::to_string(100 + i)}, {"Note", "free text, with = and spaces"}};
    frames.push_back(std::move(f));
  }
  return frames;
}

void expectSameFrames(const std::vector<Frame>& a, const std::vector<Frame>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    SCOPED_TRACE("frame " + std::to_string(i));
    EXPECT_EQ(a[i].width, b[i].width);
    EXPECT_EQ(a[i].height, b[i].height);
    EXPECT_EQ(a[i].pixelType, b[i].pixelType);
    EXPECT_EQ(a[i].pixels, b[i].pixels);
    EXPECT_EQ(a[i].index, b[i].index);
    EXPECT_EQ(a[i].timestamp, b[i].timestamp);
    EXPECT_EQ(a[i].imageValid, b[i].imageValid);
    ASSERT_EQ(a[i].transforms.size(), b[i].transforms.size());
    for (std::size_t k = 0; k < a[i].transforms.size(); ++k) {
      EXPECT_EQ(a[i].transforms[k].name, b[i].transforms[k].name);
      EXPECT_EQ(a[i].transforms[k].valid, b[i].transforms[k].valid);
      EXPECT_EQ(toRowMajor(a[i].transforms[k].matrix), toRowMajor(b[i].transforms[k].matrix));
    }
    EXPECT_EQ(a[i].customFields, b[i].customFields);
  }
}

struct RoundTripCase {
  const char* file;
  bool compress;
  SequenceFormat format;
  std::vector<std::string> expectedFiles;  // what the folder holds afterwards
};

TEST(SequenceIo, WriteReadRoundTripIsExactInEveryLayout) {
  const RoundTripCase cases[] = {
      {"a.igs.mha", false, SequenceFormat::MetaIO, {"a.igs.mha"}},
      {"b.seq.mha", true, SequenceFormat::MetaIO, {"b.seq.mha"}},
      {"c.mhd", false, SequenceFormat::MetaIO, {"c.mhd", "c.raw"}},
      {"d.mhd", true, SequenceFormat::MetaIO, {"d.mhd", "d.zraw"}},
      {"e.seq.nrrd", false, SequenceFormat::Nrrd, {"e.seq.nrrd"}},
      {"f.igs.nrrd", true, SequenceFormat::Nrrd, {"f.igs.nrrd"}},
  };
  for (PixelType type : {PixelType::U8, PixelType::U16}) {
    const std::vector<Frame> frames = makeFrames(type, 7, 5, 4);
    for (const auto& c : cases) {
      SCOPED_TRACE(std::string(c.file) + (type == PixelType::U8 ? " u8" : " u16"));
      TempDir dir;
      SequenceWriteOptions opt;
      opt.compress = c.compress;
      opt.fields = {{"UltrasoundImageType", "BRIGHTNESS"}};
      writeAllFrames(dir / c.file, frames, opt);
      EXPECT_EQ(dir.list(), c.expectedFiles);  // no temporary files left over

      SequenceInfo info;
      const std::vector<Frame> back = readAllFrames(dir / c.file, &info);
      expectSameFrames(frames, back);
      EXPECT_EQ(info.format, c.format);
      EXPECT_EQ(info.compressed, c.compress);
      EXPECT_EQ(info.frameCount, frames.size());
      EXPECT_EQ(info.pixelType, type);
      EXPECT_EQ(info.orientation, "MF");
      EXPECT_EQ(info.fields, opt.fields);

      // Writing what was read gives the same files again, byte for byte.
      TempDir again;
      opt.fields = info.fields;
      writeAllFrames(again / c.file, back, opt);
      for (const auto& name : c.expectedFiles) EXPECT_EQ(test::readBytes(dir / name), test::readBytes(again / name));
    }
  }
}

TEST(SequenceIo, MetaIoLayoutIsWhatPlusWrites) {
  TempDir dir;
  writeAllFrames(dir / "x.igs.mha", makeFrames(PixelType::U8, 3, 2, 2));
  const std::string header = test::splitFile(dir / "x.igs.mha").header();
  EXPECT_EQ(test::headerValue(header, "DimSize"), "3 2 2");
  EXPECT_EQ(test::headerValue(header, "ElementType"), "MET_UCHAR");
  EXPECT_EQ(test::headerValue(header, "CompressedData"), "True");
  EXPECT_EQ(test::headerValue(header, "Kinds"), "domain domain list");
  EXPECT_EQ(test::headerValue(header, "UltrasoundImageOrientation"), "MF");
  EXPECT_EQ(test::headerValue(header, "Seq_Frame0001_ProbeToTrackerTransformStatus"), "INVALID");
  EXPECT_EQ(test::headerValue(header, "Seq_Frame0001_ImageStatus"), "OK");
  EXPECT_EQ(test::headerValue(header, "Seq_Frame0001_FrameNumber"), "101");
  EXPECT_EQ(test::numbers(test::headerValue(header, "Seq_Frame0000_ReferenceToTrackerTransform")).size(), 16u);
  // The data block follows the last header line and is exactly CompressedDataSize long.
  const test::RawFile raw = test::splitFile(dir / "x.igs.mha");
  EXPECT_EQ(std::to_string(raw.data().size()), test::headerValue(header, "CompressedDataSize"));

  writeAllFrames(dir / "x.igs.nrrd", makeFrames(PixelType::U16, 3, 2, 2));
  const std::string nrrd = test::splitFile(dir / "x.igs.nrrd").header();
  EXPECT_EQ(nrrd.substr(0, 9), "NRRD0004\n");
  EXPECT_EQ(test::headerValue(nrrd, "type"), "uint16");
  EXPECT_EQ(test::headerValue(nrrd, "encoding"), "gzip");
  EXPECT_EQ(test::headerValue(nrrd, "kinds"), "domain domain list");
  EXPECT_EQ(test::headerValue(nrrd, "Seq_Frame0001_Status"), "OK");
  EXPECT_EQ(test::headerValue(nrrd, "ultrasound image orientation"), "MF");
}

// ------------------------------------------------------------ orientation

// A hand-written MetaIO sequence: one 3x2 frame, pixels 1..6 row by row.
std::string handMadeSequence(TempDir& dir, const std::string& orientation, bool u16 = false, bool msb = false) {
  std::string text = "ObjectType = Image\nNDims = 3\nDimSize = 3 2 1\n";
  text += std::string("ElementType = ") + (u16 ? "MET_USHORT" : "MET_UCHAR") + "\n";
  text += std::string("BinaryDataByteOrderMSB = ") + (msb ? "True" : "False") + "\n";
  text += "UltrasoundImageOrientation = " + orientation + "\nElementDataFile = LOCAL\n";
  for (int v = 1; v <= 6; ++v) {
    if (u16 && msb) text += '\x01';
    text += static_cast<char>(v);
    if (u16 && !msb) text += '\x01';
  }
  const std::string path = dir / (orientation + (u16 ? "16" : "8") + ".mha");
  test::writeBytes(path, text);
  return path;
}

std::vector<double> values(const Frame& f) {
  std::vector<double> v;
  for (int y = 0; y < f.height; ++y)
    for (int x = 0; x < f.width; ++x) v.push_back(f.value(x, y));
  return v;
}

TEST(SequenceIo, OrientationIsFlippedToMF) {
  TempDir dir;
  const std::vector<std::pair<std::string, std::vector<double>>> cases = {
      {"MF", {1, 2, 3, 4, 5, 6}}, {"MFA", {1, 2, 3, 4, 5, 6}}, {"UF", {3, 2, 1, 6, 5, 4}},
      {"MN", {4, 5, 6, 1, 2, 3}}, {"UN", {6, 5, 4, 3, 2, 1}},  {"UNA", {6, 5, 4, 3, 2, 1}},
  };
  for (const auto& [code, expected] : cases) {
    SCOPED_TRACE(code);
    SequenceInfo info;
    auto frames = readAllFrames(handMadeSequence(dir, code), &info);
    ASSERT_EQ(frames.size(), 1u);
    EXPECT_EQ(info.orientation, code);
    EXPECT_EQ(values(frames[0]), expected);
    // 16-bit pixels flip as whole pixels; 256 is the high byte every value carries.
    auto wide = readAllFrames(handMadeSequence(dir, code, true));
    std::vector<double> expected16;
    for (double v : expected) expected16.push_back(v + 256);
    EXPECT_EQ(values(wide[0]), expected16);
  }
}

TEST(SequenceIo, BigEndianSixteenBitPixelsAreSwapped) {
  TempDir dir;
  auto frames = readAllFrames(handMadeSequence(dir, "MF", true, true));
  EXPECT_EQ(values(frames[0]), (std::vector<double>{257, 258, 259, 260, 261, 262}));
}

TEST(SequenceIo, WritingAnotherOrientationStoresFlippedPixelsAndReadsBackAsMF) {
  TempDir dir;
  const auto frames = makeFrames(PixelType::U16, 5, 3, 2);
  SequenceWriteOptions opt;
  opt.orientation = "UN";
  opt.compress = false;
  writeAllFrames(dir / "un.mha", frames, opt);
  const test::RawFile raw = test::splitFile(dir / "un.mha");
  EXPECT_EQ(test::headerValue(raw.header(), "UltrasoundImageOrientation"), "UN");
  // Stored pixel (0,0) is MF pixel (4,2): both axes reversed.
  const std::string data = raw.data();
  EXPECT_EQ(static_cast<std::uint8_t>(data[0]), frames[0].pixels[(2 * 5 + 4) * 2]);
  EXPECT_EQ(static_cast<std::uint8_t>(data[1]), frames[0].pixels[(2 * 5 + 4) * 2 + 1]);
  expectSameFrames(frames, readAllFrames(dir / "un.mha"));
}

TEST(SequenceIo, UnsupportedOrientationIsAnInputError) {
  TempDir dir;
  const std::string path = handMadeSequence(dir, "FM");
  try {
    SequenceReader::open(path);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("UltrasoundImageOrientation 'FM' is not supported"), std::string::npos)
        << e.what();
  }
  SequenceWriteOptions opt;
  opt.orientation = "XY";
  EXPECT_THROW(SequenceWriter::create(dir / "x.mha", opt), InputError);
}

// ------------------------------------------------------------ streaming, atomic writes

TEST(SequenceIo, ReaderStreamsFramesIntoTheCallersBuffer) {
  auto reader = SequenceReader::open(test::dataFile("NwirePhantomFreehandCropped.igs.mha"));
  Frame f;
  ASSERT_TRUE(reader->next(f));
  const std::uint8_t* buffer = f.pixels.data();
  std::uint64_t n = 1;
  while (reader->next(f)) {
    EXPECT_EQ(f.pixels.data(), buffer) << "the frame buffer is reused";
    ++n;
  }
  EXPECT_EQ(n, 20u);
  EXPECT_FALSE(reader->next(f)) << "stays at the end";
}

TEST(SequenceIo, WriterDestroyedWithoutCloseLeavesNothing) {
  TempDir dir;
  const auto frames = makeFrames(PixelType::U8, 4, 4, 3);
  for (const char* name : {"x.mha", "x.mhd", "x.nrrd"}) {
    SCOPED_TRACE(name);
    {
      auto w = SequenceWriter::create(dir / name);
      w->write(frames[0]);
      w->write(frames[1]);
    }
    EXPECT_TRUE(dir.list().empty());
  }
  // An existing file is untouched until the new one is complete.
  writeAllFrames(dir / "keep.mha", frames);
  const std::string before = test::readBytes(dir / "keep.mha");
  {
    auto w = SequenceWriter::create(dir / "keep.mha");
    w->write(frames[2]);
  }
  EXPECT_EQ(test::readBytes(dir / "keep.mha"), before);
  EXPECT_EQ(dir.list(), std::vector<std::string>{"keep.mha"});
}

TEST(SequenceIo, WriterRejectsFramesItCannotStoreFaithfully) {
  TempDir dir;
  auto frames = makeFrames(PixelType::U8, 4, 4, 2);
  {
    auto w = SequenceWriter::create(dir / "x.mha");
    w->write(frames[0]);
    Frame other = frames[1];
    other.allocate(5, 4, PixelType::U8);
    EXPECT_THROW(w->write(other), InputError);
  }
  for (const auto& field : std::vector<std::pair<std::string, std::string>>{
           {"FooTransform", "1"}, {"Timestamp", "2"}, {"Bad\nKey", "x"}, {"Key", "line\nbreak"}}) {
    SCOPED_TRACE(field.first);
    Frame f = frames[0];
    f.customFields = {field};
    EXPECT_THROW(writeAllFrames(dir / "y.mha", {f}), InputError);
  }
  EXPECT_TRUE(dir.list().empty());
}

TEST(SequenceIo, EmptySequenceRoundTrips) {
  TempDir dir;
  for (const char* name : {"empty.mha", "empty.nrrd"}) {
    writeAllFrames(dir / name, {});
    SequenceInfo info;
    EXPECT_TRUE(readAllFrames(dir / name, &info).empty());
    EXPECT_EQ(info.frameCount, 0u);
  }
}

TEST(SequenceIo, ProbeTellsSequencesFromVolumes) {
  EXPECT_EQ(probeImageFile(test::dataFile("NwirePhantomFreehandCropped.igs.mha")), ImageFileKind::Sequence);
  EXPECT_EQ(probeImageFile(test::dataFile("NwirePhantomFreehand.igs.nrrd")), ImageFileKind::Sequence);
  EXPECT_EQ(probeImageFile(test::dataFile("vtkVolumeReconstructorTestNNMEANvolumeRef.mha")), ImageFileKind::Volume);
  // Its third axis is called a list, but it has no per-frame fields.
  EXPECT_EQ(probeImageFile(test::dataFile("SpinePhantomFreehandReconstructed.mha")), ImageFileKind::Volume);
}

// ---- a recording's journal (formats/recording_journal.hpp) ----

// Journals `frames` for a sequence at `seq` and leaves the journal behind, as a
// killed recording does.
void journal(const std::string& seq, const std::vector<Frame>& frames, const SequenceWriteOptions& opt = {}) {
  JournalWriter j(seq, opt);
  for (const auto& f : frames) j.append(f);
}

TEST(RecordingJournal, ReadsBackEveryFrameExactly) {
  for (PixelType type : {PixelType::U8, PixelType::U16}) {
    TempDir dir;
    const auto frames = makeFrames(type, 7, 5, 4);
    SequenceWriteOptions opt;
    opt.fields = {{"UltrasoundImageType", "BRIGHTNESS"}};
    journal(dir / "scan.igs.mha", frames, opt);
    EXPECT_EQ(dir.list(), std::vector<std::string>{"scan.igs.mha.journal"});
    SequenceInfo info;
    expectSameFrames(frames, readAllFrames(dir / "scan.igs.mha.journal", &info));
    EXPECT_EQ(info.frameCount, 4u);
    EXPECT_EQ(info.pixelType, type);
    EXPECT_EQ(info.fields, opt.fields);
    EXPECT_EQ(probeImageFile(dir / "scan.igs.mha.journal"), ImageFileKind::Sequence);
    auto r = SequenceReader::open(dir / "scan.igs.mha.journal");
    EXPECT_EQ(toRowMajor(r->metadata(3).transforms[0].matrix), toRowMajor(frames[3].transforms[0].matrix));
  }
}

// A process killed in the middle of a write leaves a journal cut at any byte:
// every frame whose record is whole reads back, the cut one does not, and the
// reader says where it stopped.
TEST(RecordingJournal, CutAtEveryByteKeepsEveryCompleteFrame) {
  TempDir dir;
  const auto frames = makeFrames(PixelType::U8, 6, 4, 3);
  journal(dir / "scan.mha", frames);
  const std::string whole = test::readBytes(dir / "scan.mha.journal");
  // Where each record ends: the journal of the first k frames.
  std::vector<std::size_t> ends;
  for (std::size_t k = 0; k <= frames.size(); ++k) {
    TempDir d;
    journal(d / "scan.mha", std::vector<Frame>(frames.begin(), frames.begin() + static_cast<long>(k)));
    ends.push_back(test::readBytes(d / "scan.mha.journal").size());
  }
  ASSERT_EQ(ends.back(), whole.size());
  for (std::size_t cut = ends[0]; cut <= whole.size(); ++cut) {
    SCOPED_TRACE("cut at byte " + std::to_string(cut));
    test::writeBytes(dir / "cut.mha.journal", whole.substr(0, cut));
    const std::size_t complete =
        static_cast<std::size_t>(std::upper_bound(ends.begin(), ends.end(), cut) - ends.begin()) - 1;
    JournalContents c;
    auto r = openJournal(dir / "cut.mha.journal", &c);
    ASSERT_EQ(c.frames, complete);
    EXPECT_EQ(c.keptBytes, ends[complete]);
    EXPECT_EQ(c.cut.empty(), cut == ends[complete]) << c.cut;
    Frame f;
    std::vector<Frame> back;
    while (r->next(f)) back.push_back(f);
    expectSameFrames(std::vector<Frame>(frames.begin(), frames.begin() + static_cast<long>(complete)), back);
  }
  // The header cut short is not a journal at all.
  test::writeBytes(dir / "short.mha.journal", whole.substr(0, ends[0] - 2));
  EXPECT_THROW(openJournal(dir / "short.mha.journal"), InputError);
}

// A damaged record in the middle costs that record alone: each record in
// turn, flipped at its magic, checksum, length, pixels or last byte, or cut
// short (its second half gone), and every other frame is read back, the
// damage named; `restore` writes them all and keeps the journal.
TEST(RecordingJournal, ADamagedRecordCostsThatRecordAlone) {
  const auto frames = makeFrames(PixelType::U8, 6, 4, 5);
  TempDir dir;
  journal(dir / "scan.mha", frames);
  const std::string whole = test::readBytes(dir / "scan.mha.journal");
  std::vector<std::size_t> ends;  // ends[k]: where the first k records end
  for (std::size_t k = 0; k <= frames.size(); ++k) {
    TempDir d;
    journal(d / "scan.mha", std::vector<Frame>(frames.begin(), frames.begin() + static_cast<long>(k)));
    ends.push_back(test::readBytes(d / "scan.mha.journal").size());
  }
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const std::size_t start = ends[k], len = ends[k + 1] - ends[k];
    std::vector<std::pair<std::string, std::string>> damaged;
    for (const std::size_t at : {std::size_t{0}, std::size_t{5}, std::size_t{9}, len / 2, len - 1}) {
      std::string b = whole;
      b[start + at] = static_cast<char>(b[start + at] ^ 0x10);
      damaged.emplace_back("byte " + std::to_string(at) + " flipped", b);
    }
    damaged.emplace_back("cut short", whole.substr(0, start + len / 2) + whole.substr(start + len));
    for (const auto& [how, bytes] : damaged) {
      SCOPED_TRACE("record " + std::to_string(k) + ", " + how);
      std::vector<Frame> expected = frames;
      expected.erase(expected.begin() + static_cast<long>(k));
      TempDir d;
      test::writeBytes(d / "scan.mha.journal", bytes);
      JournalContents c;
      auto r = openJournal(d / "scan.mha.journal", &c);
      Frame f;
      std::vector<Frame> back;
      while (r->next(f)) back.push_back(f);
      r.reset();
      if (k + 1 == frames.size()) {
        // The last record: nothing whole follows, so it is where the journal ends.
        EXPECT_TRUE(c.damaged.empty());
        EXPECT_NE(c.cut.find("frame " + std::to_string(k)), std::string::npos) << c.cut;
      } else {
        ASSERT_EQ(c.damaged.size(), 1u);
        EXPECT_NE(c.damaged[0].find("frame " + std::to_string(k)), std::string::npos) << c.damaged[0];
        EXPECT_TRUE(c.cut.empty()) << c.cut;
      }
      expectSameFrames(expected, back);  // each with the index it was recorded with
      // restore: every whole frame in the sequence (numbered as they come);
      // the journal stays when frames after the damage were saved from it.
      const RestoreResult res = restoreJournal(d / "scan.mha.journal");
      EXPECT_EQ(res.outPath, d / "scan.mha");
      for (std::size_t i = 0; i < expected.size(); ++i) expected[i].index = i;
      expectSameFrames(expected, readAllFrames(d / "scan.mha"));
      EXPECT_EQ(std::filesystem::exists(d / "scan.mha.journal"), k + 1 < frames.size());
    }
  }
}

// `pp5echo restore`'s work: the journal's frames become the sequence the
// recording would have written, byte for byte, in every layout; the journal
// and the cut-off writer's temporaries go.
TEST(RecordingJournal, RestoreWritesTheSequenceTheRecordingWouldHave) {
  const auto frames = makeFrames(PixelType::U8, 7, 5, 4);
  for (const char* name : {"scan.igs.mha", "scan.mhd", "scan.igs.nrrd"}) {
    SCOPED_TRACE(name);
    TempDir dir, expected;
    SequenceWriteOptions opt;
    opt.fields = {{"UltrasoundImageType", "BRIGHTNESS"}};
    writeAllFrames(expected / name, frames, opt);
    journal(dir / name, frames, opt);
    test::writeBytes(dir / (std::string(".") + name + ".tmp-Ab12Cd"), "half a compressed stream");
    test::writeBytes(dir / "other.txt", "not ours");
    std::vector<std::uint64_t> progress;
    const RestoreResult res = restoreJournal(dir / (std::string(name) + ".journal"), {},
                                             [&](std::uint64_t done, std::uint64_t) { progress.push_back(done); });
    EXPECT_EQ(res.contents.frames, 4u);
    EXPECT_EQ(res.leftoverTemporaries, 1u);
    EXPECT_EQ(progress, (std::vector<std::uint64_t>{1, 2, 3, 4}));
    std::vector<std::string> want = expected.list();
    want.push_back("other.txt");
    std::sort(want.begin(), want.end());
    EXPECT_EQ(dir.list(), want);
    for (const auto& f : expected.list()) EXPECT_EQ(test::readBytes(dir / f), test::readBytes(expected / f)) << f;
  }
  // Restored elsewhere, the journal stays.
  TempDir dir;
  journal(dir / "scan.mha", frames);
  restoreJournal(dir / "scan.mha.journal", dir / "copy.mha");
  EXPECT_EQ(dir.list(), (std::vector<std::string>{"copy.mha", "scan.mha.journal"}));
  expectSameFrames(frames, readAllFrames(dir / "copy.mha"));
  // A sequence already there is never replaced: a journal moved aside and the
  // name recorded again. The journal belongs to the name it has now.
  std::filesystem::rename(dir / "scan.mha.journal", dir / "old.mha.journal");
  writeAllFrames(dir / "old.mha", {frames[0]});
  const std::string newer = test::readBytes(dir / "old.mha");
  EXPECT_THROW(restoreJournal(dir / "old.mha.journal"), InputError);
  EXPECT_EQ(test::readBytes(dir / "old.mha"), newer);
  std::filesystem::remove(dir / "old.mha");
  EXPECT_EQ(restoreJournal(dir / "old.mha.journal").outPath, dir / "old.mha");
  expectSameFrames(frames, readAllFrames(dir / "old.mha"));
  EXPECT_FALSE(std::filesystem::exists(dir / "old.mha.journal"));
  // A first record that is damaged costs itself only: the frames after it are
  // restored, and the journal is kept as it is.
  journal(dir / "torn.mha", frames);
  std::string torn = test::readBytes(dir / "torn.mha.journal");
  TempDir headerOnly;
  journal(headerOnly / "torn.mha", {});
  torn[test::readBytes(headerOnly / "torn.mha.journal").size() + 20] ^= 0x01;  // inside frame 0's body
  test::writeBytes(dir / "torn.mha.journal", torn);
  EXPECT_EQ(restoreJournal(dir / "torn.mha.journal").contents.damaged.size(), 1u);
  std::vector<Frame> afterFirst(frames.begin() + 1, frames.end());
  for (std::size_t i = 0; i < afterFirst.size(); ++i) afterFirst[i].index = i;
  expectSameFrames(afterFirst, readAllFrames(dir / "torn.mha"));
  EXPECT_EQ(test::readBytes(dir / "torn.mha.journal"), torn);
  // Cut off before its first frame: nothing was recorded; the journal is
  // removed (restoring it elsewhere is refused).
  journal(dir / "empty.mha", {});
  EXPECT_THROW(restoreJournal(dir / "empty.mha.journal", dir / "x.mha"), InputError);
  EXPECT_TRUE(restoreJournal(dir / "empty.mha.journal").outPath.empty());
  EXPECT_FALSE(std::filesystem::exists(dir / "empty.mha.journal"));
  EXPECT_FALSE(std::filesystem::exists(dir / "empty.mha"));
}

// A journal left by a recording that was cut off is never replaced by a new one.
TEST(RecordingJournal, ALeftJournalIsNeverReplaced) {
  TempDir dir;
  const auto frames = makeFrames(PixelType::U8, 4, 4, 2);
  journal(dir / "scan.mha", frames);
  const std::string before = test::readBytes(dir / "scan.mha.journal");
  try {
    JournalWriter again(dir / "scan.mha", {});
    FAIL() << "a second journal was opened over the first";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("pp5echo restore"), std::string::npos) << e.what();
  }
  EXPECT_EQ(test::readBytes(dir / "scan.mha.journal"), before);
  JournalWriter done(dir / "next.mha", {});
  done.append(frames[0]);
  // A frame a reader would refuse (a live source may send anything) is not written.
  Frame many = frames[1];
  for (int i = 0; i < 300; ++i) many.setTransform("Device" + std::to_string(i) + "ToTracker", Mat4(1.0), true);
  EXPECT_THROW(done.append(many), InputError);
  done.discard();
  EXPECT_EQ(dir.list(), std::vector<std::string>{"scan.mha.journal"});
}

}  // namespace
}  // namespace pp5
