// MetaIO headers (ITK's .mha/.mhd) as PLUS writes them: "Key = Value" lines,
// the last one ElementDataFile; with "LOCAL" the binary data starts on the
// next byte.
#include <array>
#include <filesystem>

#include "core/error.hpp"
#include "formats/image_header.hpp"
#include "core/io_util.hpp"

namespace pp5::io {

namespace {

struct MetaType {
  const char* name;
  ElementType type;
};
constexpr std::array<MetaType, 6> kMetaTypes{{{"MET_UCHAR", ElementType::U8},
                                              {"MET_USHORT", ElementType::U16},
                                              {"MET_CHAR", ElementType::I8},
                                              {"MET_SHORT", ElementType::I16},
                                              {"MET_FLOAT", ElementType::F32},
                                              {"MET_DOUBLE", ElementType::F64}}};

const char* metaTypeName(ElementType t) {
  for (const auto& m : kMetaTypes)
    if (m.type == t) return m.name;
  return "MET_OTHER";
}

// Keys this file reads or writes itself. Any other global key is kept, in
// order, as a custom field.
bool isStructural(std::string_view key) {
  // clang-format off
  static constexpr std::array<std::string_view, 23> kKeys{
      "ObjectType", "NDims", "DimSize", "ElementType", "ElementNumberOfChannels", "ElementSpacing",
      "Offset", "Origin", "Position", "TransformMatrix", "Rotation", "Orientation", "CenterOfRotation",
      "AnatomicalOrientation", "BinaryData", "BinaryDataByteOrderMSB", "ElementByteOrderMSB",
      "CompressedData", "CompressedDataSize", "Kinds", "UltrasoundImageOrientation", "ElementDataFile",
      "HeaderSize"};
  // clang-format on
  for (auto k : kKeys)
    if (k == key) return true;
  return false;
}

class MetaHeaderParser {
public:
  MetaHeaderParser(ImageHeader& h, std::FILE* f) : h_(h), f_(f) {}

  void run() {
    std::string text;
    long lineNo = 0;
    bool sawDataFile = false;
    while (!sawDataFile && readLine(f_, text, h_.path, lineNo + 1)) {
      line_ = ++lineNo;
      const std::string_view t = trim(text);
      if (t.empty()) continue;
      const auto eq = t.find('=');
      if (eq == std::string_view::npos) fail("expected 'Key = Value' but the line has no '=': {}", excerpt(t));
      const std::string_view key = trim(t.substr(0, eq));
      const std::string_view value = trim(t.substr(eq + 1));
      if (key.empty()) fail("a line has a value but no key: {}", excerpt(t));
      if (startsWith(key, kFramePrefix))
        addFrameField(h_, key, value, line_);
      else
        apply(key, value);
      sawDataFile = key == "ElementDataFile";
    }
    if (!sawDataFile) inputError(h_.path, "no 'ElementDataFile' line: not a MetaIO image, or the header is cut off");
    finish();
  }

private:
  template <typename... Args>
  [[noreturn]] void fail(fmt::format_string<Args...> f, Args&&... args) {
    inputErrorAt(h_.path, line_, f, std::forward<Args>(args)...);
  }

  std::vector<double> numbers(std::string_view key, std::string_view value) {
    auto v = parseDoubles(value);
    if (!v) fail("{} must be numbers, not {}", key, excerpt(value));
    return *v;
  }
  bool boolean(std::string_view key, std::string_view value) {
    auto v = parseBool(value);
    if (!v) fail("{} must be True or False, not {}", key, excerpt(value));
    return *v;
  }
  std::int64_t integer(std::string_view key, std::string_view value, std::int64_t lo, std::int64_t hi) {
    auto v = parseInt(value);
    if (!v || *v < lo || *v > hi) fail("{} must be a whole number from {} to {}, not {}", key, lo, hi, excerpt(value));
    return *v;
  }
  static Vec3 vec3(const std::vector<double>& v, double fill) {
    Vec3 out(fill);
    for (std::size_t i = 0; i < v.size() && i < 3; ++i) out[static_cast<int>(i)] = v[i];
    return out;
  }

  void apply(std::string_view key, std::string_view value) {
    if (key == "ObjectType") {
      if (value != "Image") fail("ObjectType is {}, but only images are supported", excerpt(value));
    } else if (key == "NDims") {
      ndims_ = static_cast<int>(integer(key, value, 1, 4));
    } else if (key == "DimSize") {
      auto v = parseInts(value);
      if (!v || v->empty()) fail("DimSize must be whole numbers, not {}", excerpt(value));
      for (auto d : *v)
        if (d < 0) fail("DimSize {} has a negative size", excerpt(value));
      h_.dims = *v;
    } else if (key == "ElementType") {
      for (const auto& m : kMetaTypes)
        if (value == m.name) h_.element = m.type;
      if (!h_.element)
        fail("unknown ElementType {} (supported: MET_UCHAR, MET_USHORT, MET_CHAR, MET_SHORT, MET_FLOAT, MET_DOUBLE)",
             excerpt(value));
    } else if (key == "ElementNumberOfChannels") {
      h_.channels = static_cast<int>(integer(key, value, 1, 256));
    } else if (key == "ElementSpacing") {
      h_.spacing = vec3(numbers(key, value), 1.0);
    } else if (key == "Offset" || key == "Origin" || key == "Position") {
      h_.origin = vec3(numbers(key, value), 0.0);
    } else if (key == "TransformMatrix" || key == "Rotation" || key == "Orientation") {
      h_.axisAligned = isIdentity(numbers(key, value));
    } else if (key == "BinaryData") {
      if (!boolean(key, value)) fail("BinaryData = False (text pixel data) is not supported");
    } else if (key == "BinaryDataByteOrderMSB" || key == "ElementByteOrderMSB") {
      h_.bigEndian = boolean(key, value);
    } else if (key == "CompressedData") {
      h_.compressed = boolean(key, value);
    } else if (key == "CompressedDataSize") {
      h_.compressedSize = static_cast<std::uint64_t>(integer(key, value, 0, INT64_MAX));
    } else if (key == "HeaderSize") {
      if (integer(key, value, -1, INT64_MAX) != 0) fail("HeaderSize other than 0 is not supported");
    } else if (key == "Kinds") {
      for (auto w : splitWords(value)) h_.kinds.emplace_back(w);
    } else if (key == "UltrasoundImageOrientation") {
      h_.orientation = value;
    } else if (key == "ElementDataFile") {
      dataFile(value);
    } else if (!isStructural(key)) {
      h_.fields.emplace_back(key, value);
    }
  }

  static bool isIdentity(const std::vector<double>& m) {
    const std::size_t n = m.size() == 9 ? 3 : m.size() == 4 ? 2 : 0;
    if (n == 0) return false;
    for (std::size_t r = 0; r < n; ++r)
      for (std::size_t c = 0; c < n; ++c)
        if (m[r * n + c] != (r == c ? 1.0 : 0.0)) return false;
    return true;
  }

  void dataFile(std::string_view value) {
    if (value == "LOCAL") {
      h_.dataPath = h_.path;
      const long pos = std::ftell(f_);
      if (pos < 0) fail("cannot tell where the data starts");
      h_.dataOffset = static_cast<std::uint64_t>(pos);
      return;
    }
    if (value.empty() || value == "LIST" || value.find('%') != std::string_view::npos)
      fail("ElementDataFile {} is not supported (use LOCAL or a single file name)", excerpt(value));
    const auto path = detachedDataPath(h_.path, value);
    if (!path) fail("ElementDataFile {} lies outside the header's folder (only a file beside the header or below it is read)", excerpt(value));
    h_.dataPath = *path;
    h_.dataOffset = 0;
  }

  void finish() {
    if (h_.dims.empty()) inputError(h_.path, "no DimSize in the header");
    if (!h_.element) inputError(h_.path, "no ElementType in the header");
    if (ndims_ != 0 && static_cast<std::size_t>(ndims_) != h_.dims.size())
      inputError(h_.path, "DimSize has {} sizes, but NDims is {}", h_.dims.size(), ndims_);
  }

  ImageHeader& h_;
  std::FILE* f_;
  long line_ = 0;
  int ndims_ = 0;
};

std::string joinNumbers(const Vec3& v, std::size_t n) {
  std::string out;
  for (std::size_t i = 0; i < n; ++i) out += (i ? " " : "") + formatDouble(v[static_cast<int>(i)]);
  return out;
}

}  // namespace

ImageHeader readMetaHeader(const std::string& path) {
  FilePtr f = openForReading(path);
  ImageHeader h;
  h.path = path;
  h.format = SequenceFormat::MetaIO;
  MetaHeaderParser(h, f.get()).run();
  return h;
}

std::string formatMetaHeader(const ImageHeader& h) {
  const std::size_t n = h.dims.size();
  PP5_CHECK(n >= 2 && n <= 3 && h.element);
  std::string out;
  auto line = [&](std::string_view key, std::string_view value) { out += fmt::format("{} = {}\n", key, value); };
  std::string zeros, identity, dims;
  for (std::size_t i = 0; i < n; ++i) {
    zeros += i ? " 0" : "0";
    dims += (i ? " " : "") + std::to_string(h.dims[i]);
    for (std::size_t j = 0; j < n; ++j) identity += (i + j ? " " : "") + std::string(i == j ? "1" : "0");
  }
  line("ObjectType", "Image");
  line("NDims", std::to_string(n));
  // PLUS writes RAI and its coordinates as they are; ITK, VTK and Slicer read
  // Offset and ElementSpacing as the physical position of voxel centres.
  line("AnatomicalOrientation", "RAI");
  line("BinaryData", "True");
  line("BinaryDataByteOrderMSB", "False");
  line("CenterOfRotation", zeros);
  line("CompressedData", h.compressed ? "True" : "False");
  if (h.compressed) line("CompressedDataSize", std::to_string(h.compressedSize.value_or(0)));
  line("DimSize", dims);
  if (!h.kinds.empty()) {
    std::string kinds;
    for (const auto& k : h.kinds) kinds += (kinds.empty() ? "" : " ") + k;
    line("Kinds", kinds);
  }
  line("ElementNumberOfChannels", std::to_string(h.channels));
  line("ElementSpacing", joinNumbers(h.spacing, n));
  line("ElementType", metaTypeName(*h.element));
  line("Offset", joinNumbers(h.origin, n));
  line("TransformMatrix", identity);
  if (!h.orientation.empty()) line("UltrasoundImageOrientation", h.orientation);
  for (const auto& [key, value] : h.fields) {
    checkHeaderText(h.path, key, value, "=");
    if (isStructural(key) || startsWith(key, kFramePrefix))
      inputError(h.path, "cannot write field '{}': the writer sets it itself", key);
    line(key, value);
  }
  for (const auto& f : h.frameFields) {
    const std::string key = fmt::format("{}{:04d}_{}", kFramePrefix, f.frame, f.key);
    checkHeaderText(h.path, key, f.value, "=");
    line(key, f.value);
  }
  line("ElementDataFile", h.dataPath.empty() ? "LOCAL" : h.dataPath);
  return out;
}

}  // namespace pp5::io
