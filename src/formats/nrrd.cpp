// NRRD headers (teem's format, as PLUS and 3D Slicer write it): a "NRRD000x"
// magic line, "field: description" lines, "key:=value" lines for everything
// else (PLUS puts its per-frame fields there), then a blank line before the data.
//
// Coordinates. PLUS writes volume positions to MetaIO as they are, with
// AnatomicalOrientation = RAI; ITK reads those numbers as physical LPS
// coordinates (ITK's "RAI" orientation code names the LPS system), and so do
// VTK and 3D Slicer. To make Slicer put a .nrrd in the same place as the .mha
// of the same volume, volumes are written with "space: left-posterior-superior"
// and the same numbers. Files in RAS (or LAS) space are converted to LPS on
// reading, so ImageHeader always holds the MetaIO-style numbers.
#include <array>
#include <cmath>
#include <filesystem>

#include "core/error.hpp"
#include "formats/image_header.hpp"
#include "core/io_util.hpp"

namespace pp5::io {

namespace {

struct NrrdType {
  const char* name;
  ElementType type;
};
// Every spelling the NRRD spec allows for the types we handle; the first of
// each is the one written.
// clang-format off
constexpr std::array<NrrdType, 20> kNrrdTypes{{
    {"uint8", ElementType::U8},           {"uchar", ElementType::U8},
    {"unsigned char", ElementType::U8},   {"uint8_t", ElementType::U8},
    {"uint16", ElementType::U16},         {"ushort", ElementType::U16},
    {"unsigned short", ElementType::U16}, {"unsigned short int", ElementType::U16},
    {"uint16_t", ElementType::U16},       {"int8", ElementType::I8},
    {"signed char", ElementType::I8},     {"int8_t", ElementType::I8},
    {"int16", ElementType::I16},          {"short", ElementType::I16},
    {"short int", ElementType::I16},      {"signed short", ElementType::I16},
    {"signed short int", ElementType::I16}, {"int16_t", ElementType::I16},
    {"float", ElementType::F32},          {"double", ElementType::F64},
}};
// clang-format on

const char* nrrdTypeName(ElementType t) {
  switch (t) {
    case ElementType::U8: return "uint8";
    case ElementType::U16: return "uint16";
    case ElementType::I8: return "int8";
    case ElementType::I16: return "int16";
    case ElementType::F32: return "float";
    case ElementType::F64: return "double";
  }
  return "?";
}

// PLUS writes UltrasoundImageOrientation as "ultrasound image orientation".
bool isOrientationKey(std::string_view key) {
  std::string k;
  for (char c : toLower(key))
    if (c != ' ' && c != '_') k += c;
  return k == "ultrasoundimageorientation";
}
constexpr std::string_view kOrientationKey = "ultrasound image orientation";

using Vector = std::optional<std::vector<double>>;  // nullopt: "none"

class NrrdHeaderParser {
public:
  NrrdHeaderParser(ImageHeader& h, std::FILE* f) : h_(h), f_(f) {}

  void run() {
    std::string text;
    if (!readLine(f_, text, h_.path, 1) || !startsWith(trim(text), "NRRD000"))
      inputError(h_.path, "not a NRRD file (the first line is not NRRD000x)");
    line_ = 1;
    bool sawBlank = false;
    while (readLine(f_, text, h_.path, line_ + 1)) {
      ++line_;
      if (text.empty()) {
        sawBlank = true;
        break;
      }
      if (text.front() == '#') continue;
      const auto kv = text.find(":=");
      const auto fd = text.find(": ");
      if (kv != std::string::npos && (fd == std::string::npos || kv < fd))
        keyValue(trim(std::string_view(text).substr(0, kv)), trim(std::string_view(text).substr(kv + 2)));
      else if (fd != std::string::npos)
        field(toLower(trim(std::string_view(text).substr(0, fd))), trim(std::string_view(text).substr(fd + 2)));
      else
        fail("expected 'field: description' or 'key:=value', found {}", excerpt(text));
    }
    if (sawBlank && h_.dataPath.empty()) {
      h_.dataPath = h_.path;
      const long pos = std::ftell(f_);
      if (pos < 0) inputError(h_.path, "cannot tell where the data starts");
      h_.dataOffset = static_cast<std::uint64_t>(pos);
    }
    if (h_.dataPath.empty()) inputError(h_.path, "no blank line after the header and no 'data file' (file cut off?)");
    finish();
  }

private:
  template <typename... Args>
  [[noreturn]] void fail(fmt::format_string<Args...> f, Args&&... args) {
    inputErrorAt(h_.path, line_, f, std::forward<Args>(args)...);
  }

  void keyValue(std::string_view key, std::string_view value) {
    if (key.empty()) fail("a 'key:=value' line has no key");
    if (startsWith(key, kFramePrefix))
      addFrameField(h_, key, value, line_);
    else if (isOrientationKey(key))
      h_.orientation = value;
    else
      h_.fields.emplace_back(key, value);
  }

  void field(const std::string& name, std::string_view value) {
    if (name == "dimension") {
      auto v = parseInt(value);
      if (!v || *v < 1 || *v > 16) fail("dimension must be a whole number from 1 to 16, not {}", excerpt(value));
      ndims_ = static_cast<int>(*v);
    } else if (name == "type") {
      for (const auto& t : kNrrdTypes)
        if (toLower(value) == t.name) h_.element = t.type;
      if (!h_.element)
        fail("unknown or unsupported type {} (supported: uint8, uint16, int8, int16, float, double)", excerpt(value));
    } else if (name == "sizes") {
      auto v = parseInts(value);
      if (!v || v->empty()) fail("sizes must be whole numbers, not {}", excerpt(value));
      for (auto d : *v)
        if (d < 0) fail("sizes {} has a negative size", excerpt(value));
      h_.dims = *v;
    } else if (name == "encoding") {
      const std::string e = toLower(value);
      if (e == "raw")
        h_.compressed = false;
      else if (e == "gz" || e == "gzip")
        h_.compressed = true;
      else
        fail("encoding {} is not supported (raw or gzip)", excerpt(value));
      sawEncoding_ = true;
    } else if (name == "endian") {
      const std::string e = toLower(value);
      if (e != "little" && e != "big") fail("endian must be little or big, not {}", excerpt(value));
      h_.bigEndian = e == "big";
    } else if (name == "kinds") {
      for (auto w : splitWords(value)) h_.kinds.emplace_back(w);
    } else if (name == "space") {
      space_ = toLower(value);
    } else if (name == "space directions") {
      directions_ = vectors(value);
    } else if (name == "space origin") {
      auto v = vectors(value);
      if (v.size() != 1 || !v[0]) fail("space origin must be one vector like (0,0,0), not {}", excerpt(value));
      origin_ = *v[0];
    } else if (name == "spacings") {
      for (auto w : splitWords(value)) spacings_.push_back(parseDouble(w).value_or(NAN));
    } else if (name == "data file" || name == "datafile") {
      dataFile(value);
    } else if (name == "byte skip" || name == "byteskip") {
      auto v = parseInt(value);
      if (!v || *v < 0) fail("byte skip {} is not supported (a size from 0 up)", excerpt(value));
      byteSkip_ = static_cast<std::uint64_t>(*v);
    } else if (name == "line skip" || name == "lineskip") {
      if (parseInt(value).value_or(-1) != 0) fail("line skip {} is not supported", excerpt(value));
    }
    // Every other field (content, space units, measurement frame, ...) does not
    // change where the data is or how it is laid out.
  }

  // "(1,0,0) (0,1,0) none" -> one entry per vector.
  std::vector<Vector> vectors(std::string_view text) {
    std::vector<Vector> out;
    std::size_t i = 0;
    while (i < text.size()) {
      if (text[i] == ' ' || text[i] == '\t') {
        ++i;
      } else if (text.substr(i, 4) == "none") {
        out.emplace_back(std::nullopt);
        i += 4;
      } else if (text[i] == '(') {
        const auto close = text.find(')', i);
        if (close == std::string_view::npos) fail("unclosed '(' in {}", excerpt(text));
        std::vector<double> v;
        std::string_view inner = text.substr(i + 1, close - i - 1);
        while (true) {
          const auto comma = inner.find(',');
          auto x = parseDouble(inner.substr(0, comma));
          if (!x) fail("bad number in vector {}", excerpt(text));
          v.push_back(*x);
          if (comma == std::string_view::npos) break;
          inner.remove_prefix(comma + 1);
        }
        out.emplace_back(std::move(v));
        i = close + 1;
      } else {
        fail("expected vectors like (1,0,0) or none, found {}", excerpt(text));
      }
    }
    return out;
  }

  void dataFile(std::string_view value) {
    if (value.empty() || startsWith(value, "LIST") || splitWords(value).size() > 1)
      fail("data file {} is not supported (a single file name only)", excerpt(value));
    const auto path = detachedDataPath(h_.path, value);
    if (!path) fail("data file {} lies outside the header's folder (only a file beside the header or below it is read)", excerpt(value));
    h_.dataPath = *path;
    h_.dataOffset = 0;
  }

  void finish() {
    if (h_.dims.empty()) inputError(h_.path, "no sizes field in the header");
    if (!h_.element) inputError(h_.path, "no type field in the header");
    if (!sawEncoding_) inputError(h_.path, "no encoding field in the header");
    if (ndims_ != 0 && static_cast<std::size_t>(ndims_) != h_.dims.size())
      inputError(h_.path, "sizes has {} entries, but dimension is {}", h_.dims.size(), ndims_);
    if (byteSkip_ > 0 && h_.compressed) inputError(h_.path, "byte skip with compressed data is not supported");
    h_.dataOffset += byteSkip_;
    // A leading non-spatial axis (RGB, vector, ...) of a 4D image holds the channels.
    if (h_.dims.size() == 4 && !(directions_.size() == 4 && directions_[0])) {
      h_.channels = static_cast<int>(std::min<std::int64_t>(h_.dims[0], 1 << 20));
      h_.dims.erase(h_.dims.begin());
      if (h_.kinds.size() == 4) h_.kinds.erase(h_.kinds.begin());
      if (directions_.size() == 4) directions_.erase(directions_.begin());
      if (spacings_.size() == 4) spacings_.erase(spacings_.begin());
    }
    geometry();
  }

  // Spacing and origin from space directions (or spacings), converted to LPS.
  void geometry() {
    Vec3 flip(1.0);
    if (space_ == "right-anterior-superior" || space_ == "ras") flip = Vec3(-1.0, -1.0, 1.0);
    if (space_ == "left-anterior-superior" || space_ == "las") flip = Vec3(1.0, -1.0, 1.0);
    for (std::size_t i = 0; i < origin_.size() && i < 3; ++i)
      h_.origin[static_cast<int>(i)] = origin_[i] * flip[static_cast<int>(i)];
    int axis = 0;
    for (const auto& d : directions_) {
      if (!d || axis >= 3) continue;
      double len2 = 0.0;
      for (std::size_t c = 0; c < d->size(); ++c) {
        len2 += (*d)[c] * (*d)[c];
        const double signedValue = (*d)[c] * (c < 3 ? flip[static_cast<int>(c)] : 1.0);
        // Only a positive step along the axis's own coordinate is axis-aligned.
        const bool own = static_cast<int>(c) == axis;
        if ((own && !(signedValue > 0.0)) || (!own && signedValue != 0.0)) h_.axisAligned = false;
      }
      h_.spacing[axis] = std::sqrt(len2);
      ++axis;
    }
    if (directions_.empty())
      for (std::size_t i = 0; i < spacings_.size() && i < 3; ++i)
        if (std::isfinite(spacings_[i])) h_.spacing[static_cast<int>(i)] = spacings_[i];
  }

  ImageHeader& h_;
  std::FILE* f_;
  long line_ = 0;
  int ndims_ = 0;
  bool sawEncoding_ = false;
  std::uint64_t byteSkip_ = 0;
  std::string space_;
  std::vector<Vector> directions_;
  std::vector<double> origin_;
  std::vector<double> spacings_;
};

std::string vectorText(const std::vector<double>& v) {
  std::string out = "(";
  for (std::size_t i = 0; i < v.size(); ++i) out += (i ? "," : "") + formatDouble(v[i]);
  return out + ")";
}

}  // namespace

ImageHeader readNrrdHeader(const std::string& path) {
  FilePtr f = openForReading(path);
  ImageHeader h;
  h.path = path;
  h.format = SequenceFormat::Nrrd;
  NrrdHeaderParser(h, f.get()).run();
  return h;
}

std::string formatNrrdHeader(const ImageHeader& h) {
  const std::size_t n = h.dims.size();
  PP5_CHECK(n == 3 && h.element && h.channels == 1);
  std::string out =
      "NRRD0004\n# Complete NRRD file format specification at:\n# http://teem.sourceforge.net/nrrd/format.html\n";
  auto line = [&](std::string_view name, std::string_view value) { out += fmt::format("{}: {}\n", name, value); };
  line("type", nrrdTypeName(*h.element));
  line("dimension", std::to_string(n));
  if (h.isSequence) {
    // As PLUS writes sequences: a 2D space for the frames, the third axis a list.
    line("space dimension", "2");
  } else {
    line("space", "left-posterior-superior");
  }
  line("sizes", fmt::format("{} {} {}", h.dims[0], h.dims[1], h.dims[2]));
  if (h.isSequence) {
    line("space directions", "(1,0) (0,1) none");
  } else {
    line("space directions", fmt::format("{} {} {}", vectorText({h.spacing.x, 0.0, 0.0}),
                                         vectorText({0.0, h.spacing.y, 0.0}), vectorText({0.0, 0.0, h.spacing.z})));
  }
  std::string kinds;
  for (const auto& k : h.kinds) kinds += (kinds.empty() ? "" : " ") + k;
  if (!kinds.empty()) line("kinds", kinds);
  line("endian", "little");
  line("encoding", h.compressed ? "gzip" : "raw");
  line("space origin", h.isSequence ? "(0,0)" : vectorText({h.origin.x, h.origin.y, h.origin.z}));
  if (!h.dataPath.empty()) line("data file", h.dataPath);
  auto keyValue = [&](std::string_view key, std::string_view value) {
    checkHeaderText(h.path, key, value, ":");
    out += fmt::format("{}:={}\n", key, value);
  };
  if (!h.orientation.empty()) keyValue(kOrientationKey, h.orientation);
  for (const auto& [key, value] : h.fields) {
    if (isOrientationKey(key) || startsWith(key, kFramePrefix))
      inputError(h.path, "cannot write field '{}': the writer sets it itself", key);
    keyValue(key, value);
  }
  for (const auto& f : h.frameFields) keyValue(fmt::format("{}{:04d}_{}", kFramePrefix, f.frame, f.key), f.value);
  return out + "\n";
}

}  // namespace pp5::io
