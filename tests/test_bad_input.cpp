// Bad sequence and volume files: each gives one InputError line naming the
// file and what is wrong, and never a crash (run these under ASan/UBSan too).
#include <gtest/gtest.h>

#include <functional>

#include "core/error.hpp"
#include "formats/sequence_io.hpp"
#include "formats/volume_io.hpp"
#include "io_test_util.hpp"

namespace pp5 {
namespace {

using test::TempDir;

const char* const kSmall = "NwirePhantomFreehandCropped.igs.mha";  // 20 frames of 200x150, compressed

// Runs `action` and returns the InputError's message; fails the test if there
// is none, or if the message is not one line naming `path`.
std::string inputErrorOf(const std::function<void()>& action, const std::string& path) {
  try {
    action();
  } catch (const InputError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(path), std::string::npos) << "message does not name the file: " << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << "message is not one line: " << msg;
    return msg;
  } catch (const std::exception& e) {
    ADD_FAILURE() << "not an InputError: " << e.what();
    return "";
  }
  ADD_FAILURE() << "no error for " << path;
  return "";
}

void readAll(const std::string& path) { readAllFrames(path); }

#define EXPECT_CONTAINS(text, piece) EXPECT_NE((text).find(piece), std::string::npos) << "in: " << (text)

// The small real sequence with its header text edited (the data is untouched).
std::string editedCopy(const TempDir& dir, const std::string& name, const std::string& from, const std::string& to) {
  test::RawFile raw = test::splitFile(test::dataFile(kSmall));
  std::string header = raw.header();
  const auto pos = header.find(from);
  if (pos == std::string::npos) throw std::runtime_error("test: '" + from + "' not in header");
  header.replace(pos, from.size(), to);
  const std::string path = dir / name;
  test::writeBytes(path, header + raw.data());
  return path;
}

// A small uncompressed sequence written by the code under test.
std::string uncompressedCopy(const TempDir& dir, const std::string& name) {
  std::vector<Frame> frames = readAllFrames(test::dataFile(kSmall));
  frames.resize(5);
  SequenceWriteOptions opt;
  opt.compress = false;
  writeAllFrames(dir / name, frames, opt);
  return dir / name;
}

TEST(BadInput, MissingFile) {
  TempDir dir;
  const std::string path = dir / "no-such-file.igs.mha";
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "cannot open");
  EXPECT_CONTAINS(inputErrorOf([&] { readVolume(path); }, path), "No such file");
  const std::string folder = dir / "folder.mha";
  std::filesystem::create_directory(folder);
  EXPECT_CONTAINS(inputErrorOf([&] { readVolumeHeader(folder); }, folder), "it is a folder");
  // A .mhd whose data file is gone: the message names the header and the data file.
  const std::vector<Frame> frames = readAllFrames(test::dataFile(kSmall));
  writeAllFrames(dir / "x.mhd", frames);
  std::filesystem::remove(dir / "x.zraw");
  const std::string mhd = dir / "x.mhd";
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(mhd); }, mhd),
                  "its data file: " + (dir / "x.zraw") + ": cannot open");
  const std::string odd = dir / "file.png";
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(odd); }, odd), "unknown file type");
}

// A header's data file is read only beside the header or below its folder: a
// header naming /etc/passwd or climbing out with ".." is refused before
// anything is opened (a server reads headers that others send).
TEST(BadInput, ADataFileOutsideTheHeadersFolderIsNotRead) {
  TempDir dir;
  std::vector<Frame> frames = readAllFrames(test::dataFile(kSmall));
  frames.resize(3);
  SequenceWriteOptions opt;
  opt.compress = false;
  std::filesystem::create_directories(dir / "sub");
  writeAllFrames(dir / "sub/x.mhd", frames, opt);
  const std::string header = test::readBytes(dir / "sub/x.mhd");
  const std::string line = "ElementDataFile = x.raw";
  ASSERT_NE(header.find(line), std::string::npos) << header;
  auto withDataFile = [&](const std::string& name, const std::string& value) {
    std::string h = header;
    h.replace(h.find(line), line.size(), "ElementDataFile = " + value);
    const std::string path = dir / name;
    test::writeBytes(path, h);
    return path;
  };
  for (const std::string& bad : {std::string("/etc/passwd"), std::string("../sub/x.raw"), std::string("sub/../../x.raw"),
                                 (dir / "sub/x.raw")}) {
    const std::string path = withDataFile("bad.mhd", bad);
    EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "lies outside the header's folder");
  }
  // Below the header's folder is fine, and reads the same frames.
  const std::string ok = withDataFile("ok.mhd", "sub/x.raw");
  const std::vector<Frame> back = readAllFrames(ok);
  ASSERT_EQ(back.size(), frames.size());
  EXPECT_EQ(back[2].pixels, frames[2].pixels);
  // NRRD's data file, in a volume header, the same.
  const std::string nhdr = dir / "v.nhdr";
  test::writeBytes(nhdr, "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nspacings: 1 1 1\nencoding: raw\n"
                         "data file: /etc/passwd\n\n");
  EXPECT_CONTAINS(inputErrorOf([&] { readVolume(nhdr); }, nhdr), "lies outside the header's folder");
}

TEST(BadInput, TruncatedCompressedFile) {
  TempDir dir;
  const test::RawFile raw = test::splitFile(test::dataFile(kSmall));
  const std::string path = dir / "cut.igs.mha";
  test::writeBytes(path, raw.bytes.substr(0, raw.dataStart + 5000));
  const std::string msg = inputErrorOf([&] { readAll(path); }, path);
  EXPECT_CONTAINS(msg, "CompressedDataSize is 20002 bytes, but the data after the header is only 5000");
  EXPECT_CONTAINS(msg, "truncated");

  // Cut inside the header: no ElementDataFile line.
  test::writeBytes(path, raw.bytes.substr(0, raw.dataStart / 2));
  EXPECT_CONTAINS(inputErrorOf([&] { readAll(path); }, path), "no 'ElementDataFile' line");
}

TEST(BadInput, TruncatedUncompressedFileNamesTheFrame) {
  TempDir dir;
  const std::string path = uncompressedCopy(dir, "raw.mha");
  const std::string bytes = test::readBytes(path);
  // Five 200x150 frames; cut in the middle of frame 3.
  test::writeBytes(path, bytes.substr(0, bytes.size() - 30000 - 15000));
  const std::string msg = inputErrorOf([&] { readAll(path); }, path);
  EXPECT_CONTAINS(msg, "the data after the header is 105000 bytes, shorter than the 150000");
  EXPECT_CONTAINS(msg, "it ends in frame 3");
}

TEST(BadInput, DimSizeNotMatchingTheData) {
  TempDir dir;
  // One frame more than the compressed data holds.
  std::string path = editedCopy(dir, "more.mha", "DimSize = 200 150 20", "DimSize = 200 150 21");
  std::string msg = inputErrorOf([&] { readAll(path); }, path);
  EXPECT_CONTAINS(msg, "frame 20: the compressed data ends 0 bytes into this frame");
  // Frames half as wide: the data holds more than the header claims.
  path = editedCopy(dir, "less.mha", "DimSize = 200 150 20", "DimSize = 100 150 20");
  msg = inputErrorOf([&] { readAll(path); }, path);
  EXPECT_CONTAINS(msg, "holds more than the 20 frames");
  // Uncompressed: checked against the file size on open.
  const std::string raw = uncompressedCopy(dir, "raw.mha");
  test::writeBytes(raw, test::readBytes(raw) + "extra");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(raw); }, raw), "longer than the 150000");
  // Per-frame fields for frames the header does not declare.
  path = editedCopy(dir, "fewer.mha", "DimSize = 200 150 20", "DimSize = 200 150 19");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path),
                  "Seq_Frame0019_ImageToCroppedImageTransform is for frame 19, but the header declares only 19 frames");
}

TEST(BadInput, BadTransforms) {
  TempDir dir;
  const test::RawFile raw = test::splitFile(test::dataFile(kSmall));
  const std::string key = "Seq_Frame0003_ProbeToTrackerTransform = ";
  const std::string line = test::headerValue(raw.header(), "Seq_Frame0003_ProbeToTrackerTransform");
  const std::string fifteen = line.substr(0, line.rfind(' '));
  std::string path = editedCopy(dir, "15.mha", key + line, key + fifteen);
  std::string msg = inputErrorOf([&] { SequenceReader::open(path); }, path);
  EXPECT_CONTAINS(msg, "frame 3: Seq_Frame0003_ProbeToTrackerTransform is not a 4x4 matrix");
  EXPECT_CONTAINS(msg, "15");

  path = editedCopy(dir, "nan.mha", key + line, key + "abc" + line.substr(line.find(' ')));
  msg = inputErrorOf([&] { SequenceReader::open(path); }, path);
  EXPECT_CONTAINS(msg, "frame 3: Seq_Frame0003_ProbeToTrackerTransform is not a 4x4 matrix");
  EXPECT_CONTAINS(msg, "'abc' is not a number");

  path = editedCopy(dir, "ts.mha", "Seq_Frame0002_Timestamp = ", "Seq_Frame0002_Timestamp = soon");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path),
                  "frame 2: Seq_Frame0002_Timestamp is not a number");
}

TEST(BadInput, UnknownOrUnsupportedElementType) {
  TempDir dir;
  std::string path = editedCopy(dir, "foo.mha", "MET_UCHAR", "MET_FOO");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "unknown ElementType 'MET_FOO'");
  path = editedCopy(dir, "float.mha", "MET_UCHAR", "MET_FLOAT");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "pixel type float32 is not supported");
  path = editedCopy(dir, "rgb.mha", "ElementNumberOfChannels = 1", "ElementNumberOfChannels = 3");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "multi-channel");
}

TEST(BadInput, CorruptZlibStream) {
  TempDir dir;
  test::RawFile raw = test::splitFile(test::dataFile(kSmall));
  // Garbage over a stretch in the middle of the compressed data.
  for (std::size_t i = raw.dataStart + 9000; i < raw.dataStart + 9400; ++i) raw.bytes[i] = '\xff';
  const std::string path = dir / "corrupt.igs.mha";
  test::writeBytes(path, raw.bytes);
  const std::string msg = inputErrorOf([&] { readAll(path); }, path);
  EXPECT_CONTAINS(msg, "corrupt compressed data");
  EXPECT_CONTAINS(msg, "frame ");

  // A wrong zlib header fails on the first frame.
  raw = test::splitFile(test::dataFile(kSmall));
  raw.bytes[raw.dataStart] = 'Z';
  test::writeBytes(path, raw.bytes);
  EXPECT_CONTAINS(inputErrorOf([&] { readAll(path); }, path), "frame 0: corrupt compressed data");
}

TEST(BadInput, NegativeOrAbsurdDimSize) {
  TempDir dir;
  std::string path = editedCopy(dir, "neg.mha", "DimSize = 200 150 20", "DimSize = -200 150 20");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "negative size");
  path = editedCopy(dir, "huge.mha", "DimSize = 200 150 20", "DimSize = 2000000 3000000 20");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "larger than the 1 GiB limit");
  path = editedCopy(dir, "many.mha", "DimSize = 200 150 20", "DimSize = 200 150 2000000000");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "more than 20002 bytes of compressed data");
  path = editedCopy(dir, "overflow.mha", "DimSize = 200 150 20", "DimSize = 200 150 99999999999999999999");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "DimSize must be whole numbers");
  path = editedCopy(dir, "ndims.mha", "NDims = 3", "NDims = 2");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "DimSize has 3 sizes, but NDims is 2");

  // Volumes: checked against the data before any allocation.
  const test::RawFile vol = test::splitFile(test::dataFile("vtkVolumeReconstructorTestLNMEANvolumeRef.mha"));
  std::string header = vol.header();
  header.replace(header.find("DimSize = 80 93"), 15, "DimSize = 80000 93000");
  path = dir / "hugevol.mha";
  test::writeBytes(path, header + vol.data());
  EXPECT_CONTAINS(inputErrorOf([&] { readVolume(path); }, path), "shorter than the");
  const test::RawFile zvol = test::splitFile(test::dataFile("SpinePhantomFreehandReconstructed.mha"));
  header = zvol.header();
  header.replace(header.find("DimSize = 147 106 104"), 21, "DimSize = 147000 106000 104");
  path = dir / "hugezvol.mha";
  test::writeBytes(path, header + zvol.data());
  EXPECT_CONTAINS(inputErrorOf([&] { readVolume(path); }, path), "of compressed data can hold");
}

TEST(BadInput, HeaderLineWithoutEquals) {
  TempDir dir;
  const std::string path = editedCopy(dir, "noeq.mha", "BinaryData = True\n", "BinaryData = True\nthis is no header\n");
  const std::string msg = inputErrorOf([&] { SequenceReader::open(path); }, path);
  EXPECT_CONTAINS(msg, "noeq.mha:5: expected 'Key = Value' but the line has no '='");
  // A binary file given by mistake.
  const std::string bin = dir / "binary.mha";
  test::writeBytes(bin, std::string(3u << 20, 'x'));
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(bin); }, bin), "longer than");
}

TEST(BadInput, TruncatedVolume) {
  TempDir dir;
  const std::string bytes = test::readBytes(test::dataFile("vtkVolumeReconstructorTestNNLATEvolumeRef.mha"));
  const std::string path = dir / "cut.mha";
  test::writeBytes(path, bytes.substr(0, bytes.size() - 1000));
  EXPECT_CONTAINS(inputErrorOf([&] { readVolume(path); }, path), "(file truncated, or DimSize wrong)");
  EXPECT_NO_THROW(readVolumeHeader(path));  // the header alone is fine
  // `info`'s check says what readVolume would: the data is short.
  EXPECT_CONTAINS(inputErrorOf([&] { checkVolumeFile(path); }, path), "(file truncated, or DimSize wrong)");
}

// What `pp5echo info` checks of a volume without reading its data: the
// geometry readVolume and `evaluate` refuse, and a size the file does not hold.
TEST(BadInput, AVolumesGeometryAndSizeAreChecked) {
  TempDir dir;
  const std::string good = test::readBytes(test::dataFile("vtkVolumeReconstructorTestNNLATEvolumeRef.mha"));
  auto edited = [&](const std::string& name, const std::string& from, const std::string& to) {
    std::string bytes = good;
    bytes.replace(bytes.find(from), from.size(), to);
    test::writeBytes(dir / name, bytes);
    return dir / name;
  };
  EXPECT_NO_THROW(checkVolumeFile(edited("good.mha", "NDims", "NDims")));
  const std::pair<std::string, std::string> bad[] = {
      {"ElementSpacing = 0.5 0.5 0.5", "ElementSpacing = 0.5 nan 0.5"},
      {"ElementSpacing = 0.5 0.5 0.5", "ElementSpacing = 0.5 0 0.5"},
      {"ElementSpacing = 0.5 0.5 0.5", "ElementSpacing = 0.5 -0.5 0.5"},
      {"DimSize = 80 93                       98", "DimSize = 80 0 98"},
      {"DimSize = 80 93                       98", "DimSize = 2000 2000 2000"},  // 8 GB claimed
  };
  for (const auto& [from, to] : bad) {
    const std::string path = edited("bad.mha", from, to);
    const std::string msg = inputErrorOf([&] { checkVolumeFile(path); }, path);
    bool refusedByRead = false;
    try {
      readVolume(path);
    } catch (const InputError&) {
      refusedByRead = true;
    }
    EXPECT_TRUE(refusedByRead) << to;  // the same file readVolume refuses
    EXPECT_FALSE(msg.empty()) << to;
  }
}

TEST(BadInput, BadNrrd) {
  TempDir dir;
  const std::string good = test::readBytes(test::dataFile("NwirePhantomFreehand.igs.nrrd"));
  auto edited = [&](const std::string& name, const std::string& from, const std::string& to) {
    std::string bytes = good;
    bytes.replace(bytes.find(from), from.size(), to);
    test::writeBytes(dir / name, bytes);
    return dir / name;
  };
  std::string path = edited("type.nrrd", "type: uint8", "type: int64");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "unknown or unsupported type 'int64'");
  path = edited("enc.nrrd", "encoding: gz", "encoding: bzip2");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "encoding 'bzip2' is not supported");
  path = edited("magic.nrrd", "NRRD0004", "NRRX0004");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "not a NRRD file");
  path = edited("line.nrrd", "endian: little", "endian little");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "expected 'field: description'");
  path = edited("status.nrrd", "Seq_Frame0005_Timestamp:=", "Seq_Frame0005_Timestamp:=x");
  EXPECT_CONTAINS(inputErrorOf([&] { SequenceReader::open(path); }, path), "frame 5:");
  path = dir / "cut.nrrd";
  test::writeBytes(path, good.substr(0, good.size() / 2));
  EXPECT_CONTAINS(inputErrorOf([&] { readAll(path); }, path),
                  "the compressed data stops before the zlib stream ends (file truncated?)");
}

TEST(BadInput, CommandLinePrintsOneLineAndExitsOne) {
  TempDir dir;
  test::RawFile raw = test::splitFile(test::dataFile(kSmall));
  for (std::size_t i = raw.dataStart + 9000; i < raw.dataStart + 9400; ++i) raw.bytes[i] = '\xff';
  const std::string corrupt = dir / "corrupt.igs.mha";
  test::writeBytes(corrupt, raw.bytes);
  for (const std::string& path : {dir / "missing.igs.mha", corrupt}) {
    SCOPED_TRACE(path);
    const test::CommandResult r = test::runCommand(std::string("'") + PP5_BINARY + "' info '" + path + "'");
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_EQ(r.out, "");
    ASSERT_FALSE(r.err.empty());
    EXPECT_EQ(r.err.find('\n'), r.err.size() - 1) << "exactly one line: " << r.err;
    EXPECT_EQ(r.err.rfind("pp5echo: error: " + path + ": ", 0), 0u) << r.err;
  }
}

}  // namespace
}  // namespace pp5
