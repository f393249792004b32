#pragma once
// The header of a MetaIO or NRRD image file, reduced to what the sequence and
// volume readers and writers need. metaio.cpp and nrrd.cpp translate between
// this and their format's text; everything above them is format-free.
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "formats/sequence_io.hpp"
#include "core/transform.hpp"

namespace pp5::io {

enum class ElementType : std::uint8_t { U8, U16, I8, I16, F32, F64 };
int elementBytes(ElementType t);
const char* elementName(ElementType t);  // "uint8", ... (for messages and `info`)

using KeyValue = std::pair<std::string, std::string>;

// One "Seq_FrameNNNN_<key> = value" line. Kept flat and in file order: the
// frame count is not trusted yet when these are read.
struct FrameField {
  std::uint64_t frame = 0;
  std::string key;  // without the "Seq_FrameNNNN_" prefix
  std::string value;
  long line = 0;  // header line, for error messages (0 when written)
};

struct ImageHeader {
  std::string path;  // the header's file, named in every error
  SequenceFormat format = SequenceFormat::MetaIO;
  std::vector<std::int64_t> dims;  // x fastest; sizes as in the file
  std::optional<ElementType> element;
  int channels = 1;
  bool bigEndian = false;
  bool compressed = false;
  // MetaIO's CompressedDataSize; nullopt: the compressed data runs to the end of the file.
  std::optional<std::uint64_t> compressedSize;
  // Where the data block is: dataPath from dataOffset. When writing, dataPath
  // is the name written into the header (empty: data follows the header).
  std::string dataPath;
  std::uint64_t dataOffset = 0;

  // Geometry (volumes). Offset / space origin, and per-axis spacing, in the
  // file's own coordinates; NRRD's are converted to the MetaIO ones (see nrrd.cpp).
  Vec3 origin{0.0};
  Vec3 spacing{1.0};
  bool axisAligned = true;  // TransformMatrix / space directions without rotation

  std::vector<std::string> kinds;  // "domain domain list" for sequences
  std::string orientation;         // UltrasoundImageOrientation; empty when absent
  std::vector<KeyValue> fields;    // other global key/values, in file order
  std::vector<FrameField> frameFields;
  bool isSequence = false;  // writing only: which layout of structural fields to use
};

// Reads a header by the file's extension (.mha/.mhd: MetaIO; .nrrd/.nhdr: NRRD).
ImageHeader readImageHeader(const std::string& path);

ImageHeader readMetaHeader(const std::string& path);  // metaio.cpp
ImageHeader readNrrdHeader(const std::string& path);  // nrrd.cpp
// Header text, ending where the data begins. Throws InputError (naming
// h.path) for keys or values the format cannot hold.
std::string formatMetaHeader(const ImageHeader& h);  // metaio.cpp
std::string formatNrrdHeader(const ImageHeader& h);  // nrrd.cpp

// Splits "Seq_Frame0012_ProbeToTrackerTransform" into frame 12 and the rest
// and appends it to h.frameFields; InputError on a malformed key. Shared by both
// formats, which use the same per-frame key names.
void addFrameField(ImageHeader& h, std::string_view key, std::string_view value, long line);
constexpr std::string_view kFramePrefix = "Seq_Frame";

// Rejects a key or value that would not read back as written: line breaks,
// the format's separator in the key, or spaces at either end (readers trim them).
void checkHeaderText(const std::string& path, std::string_view key, std::string_view value, std::string_view separator);

// Bytes of one element times channels times all dims, or nullopt on overflow.
std::optional<std::uint64_t> dataBytes(const ImageHeader& h);

// The path of a header's detached data file (MetaIO's ElementDataFile, NRRD's
// data file) named `name`: a file in the header's folder or below it. None
// when the name is absolute or climbs out with "..": a header must not make
// pp5echo read files it does not name as its own (a server reads headers that
// others send). In image_file.cpp.
std::optional<std::string> detachedDataPath(const std::string& headerPath, std::string_view name);

// "820x616x21" for messages.
std::string dimsText(const std::vector<std::int64_t>& dims);

}  // namespace pp5::io
