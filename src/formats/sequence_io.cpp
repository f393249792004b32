#include "formats/sequence_io.hpp"

#include <algorithm>
#include <cmath>
#include <map>

#include "core/error.hpp"
#include "formats/image_file.hpp"
#include "formats/recording_journal.hpp"

namespace pp5 {

namespace {

using io::FrameField;
using io::ImageHeader;

// A frame larger than this is a wrong DimSize, not an ultrasound image; the
// limit keeps a bad header from asking for an absurd allocation.
constexpr std::uint64_t kMaxFrameBytes = std::uint64_t{1} << 30;

constexpr std::string_view kTransformSuffix = "Transform";
constexpr std::string_view kTransformStatusSuffix = "TransformStatus";
constexpr std::string_view kTimestampKey = "Timestamp";

// MetaIO sequences call the image status "ImageStatus", PLUS's NRRD ones "Status".
std::string_view imageStatusKey(SequenceFormat f) { return f == SequenceFormat::MetaIO ? "ImageStatus" : "Status"; }

// ------------------------------------------------------------ orientation
//
// PLUS names a frame's orientation by the transducer direction its axes run
// toward: the first letter for image x (M: the transducer's Marked side, U:
// Unmarked), the second for image y (F: Far from the transducer, N: Near). A
// third letter (A/D) describes the third axis of 3D probes and does not change
// a 2D frame. Frames are kept in MF, so UF flips x, MN flips y and UN both.
// A flip is its own inverse, so the same flip converts MF back to the file's code.
struct Flip {
  bool x = false;
  bool y = false;
  bool any() const { return x || y; }
};

std::optional<Flip> flipToMF(std::string_view code) {
  const std::string c = io::toLower(code);
  if (c.empty()) return Flip{};  // PLUS's default is MF
  if (c.size() < 2 || c.size() > 3) return std::nullopt;
  const bool xOk = c[0] == 'm' || c[0] == 'u';
  const bool yOk = c[1] == 'f' || c[1] == 'n';
  const bool zOk = c.size() == 2 || c[2] == 'a' || c[2] == 'd';
  if (!xOk || !yOk || !zOk) return std::nullopt;
  return Flip{c[0] == 'u', c[1] == 'n'};
}

Flip checkedFlip(const std::string& path, std::string_view code) {
  auto flip = flipToMF(code);
  if (!flip)
    inputError(path, "UltrasoundImageOrientation {} is not supported (MF, MN, UF or UN, optionally followed by A or D)",
               io::excerpt(code));
  return *flip;
}

void flipPixels(std::uint8_t* data, int width, int height, int bpp, Flip flip) {
  const std::size_t pixel = static_cast<std::size_t>(bpp);
  const std::size_t row = static_cast<std::size_t>(width) * pixel;
  if (flip.x) {
    for (int y = 0; y < height; ++y) {
      std::uint8_t* r = data + static_cast<std::size_t>(y) * row;
      for (int x = 0; x < width / 2; ++x)
        std::swap_ranges(r + static_cast<std::size_t>(x) * pixel, r + static_cast<std::size_t>(x + 1) * pixel,
                         r + static_cast<std::size_t>(width - 1 - x) * pixel);
    }
  }
  if (flip.y) {
    for (int y = 0; y < height / 2; ++y)
      std::swap_ranges(data + static_cast<std::size_t>(y) * row, data + static_cast<std::size_t>(y + 1) * row,
                       data + static_cast<std::size_t>(height - 1 - y) * row);
  }
}

void swapBytePairs(std::uint8_t* data, std::size_t n) {
  for (std::size_t i = 0; i + 1 < n; i += 2) std::swap(data[i], data[i + 1]);
}

// -------------------------------------------------------- per-frame fields

bool isTransformKey(std::string_view key) {
  return key.size() > kTransformSuffix.size() && io::endsWith(key, kTransformSuffix);
}
bool isTransformStatusKey(std::string_view key) {
  return key.size() > kTransformStatusSuffix.size() && io::endsWith(key, kTransformStatusSuffix);
}

FrameTransform& transformNamed(Frame& f, std::string_view name) {
  for (auto& t : f.transforms)
    if (t.name == name) return t;
  f.transforms.push_back({std::string(name), Mat4(1.0), true});
  return f.transforms.back();
}

// Builds one frame's tracking data (everything but pixels) from its header
// fields, given in file order. Shared by both formats.
Frame frameFromFields(const ImageHeader& h, std::uint64_t index, const std::vector<const FrameField*>& fields) {
  Frame meta;
  meta.index = index;
  std::vector<std::string> withMatrix;
  std::vector<std::pair<std::string, std::string>> statusText;  // kept for a status without its transform
  const std::string_view statusKey = imageStatusKey(h.format);
  for (const FrameField* f : fields) {
    auto fullKey = [&] { return fmt::format("{}{:04d}_{}", io::kFramePrefix, index, f->key); };
    if (f->key == kTimestampKey) {
      auto t = io::parseDouble(f->value);
      if (!t || !std::isfinite(*t))
        inputErrorAt(h.path, f->line, "frame {}: {} is not a number: {}", index, fullKey(), io::excerpt(f->value));
      meta.timestamp = *t;
    } else if (f->key == statusKey) {
      meta.imageValid = f->value == "OK";
    } else if (isTransformStatusKey(f->key)) {
      const std::string name = f->key.substr(0, f->key.size() - kTransformStatusSuffix.size());
      transformNamed(meta, name).valid = f->value == "OK";
      statusText.emplace_back(name, f->value);
    } else if (isTransformKey(f->key)) {
      const std::string name = f->key.substr(0, f->key.size() - kTransformSuffix.size());
      std::string why;
      auto m = parseRowMajor(f->value, &why);
      if (!m) inputErrorAt(h.path, f->line, "frame {}: {} is not a 4x4 matrix: {}", index, fullKey(), why);
      transformNamed(meta, name).matrix = *m;
      withMatrix.push_back(name);
    } else {
      meta.customFields.emplace_back(f->key, f->value);
    }
  }
  // A status whose transform never came is not a pose; keep it as the text it was.
  for (const auto& [name, text] : statusText) {
    if (std::find(withMatrix.begin(), withMatrix.end(), name) != withMatrix.end()) continue;
    const std::string& n = name;  // clang 14 cannot capture a structured binding
    std::erase_if(meta.transforms, [&](const FrameTransform& t) { return t.name == n; });
    meta.customFields.emplace_back(name + std::string(kTransformStatusSuffix), text);
  }
  return meta;
}

// 16 numbers separated by single spaces, as PLUS writes them; each is the
// shortest text that reads back as the same double.
std::string matrixText(const Mat4& m) {
  std::string out;
  for (double v : toRowMajor(m)) out += (out.empty() ? "" : " ") + io::formatDouble(v);
  return out;
}

void appendFrameFields(const std::string& path, SequenceFormat format, const Frame& f, std::uint64_t index,
                       std::vector<FrameField>& out) {
  const std::string_view statusKey = imageStatusKey(format);
  for (const auto& t : f.transforms) {
    out.push_back({index, t.name + std::string(kTransformSuffix), matrixText(t.matrix), 0});
    out.push_back({index, t.name + std::string(kTransformStatusSuffix), t.valid ? "OK" : "INVALID", 0});
  }
  if (!std::isfinite(f.timestamp)) inputError(path, "frame {}: the timestamp is not a finite number", index);
  out.push_back({index, std::string(kTimestampKey), io::formatDouble(f.timestamp), 0});
  out.push_back({index, std::string(statusKey), f.imageValid ? "OK" : "INVALID", 0});
  for (const auto& [key, value] : f.customFields) {
    if (key == kTimestampKey || key == statusKey || isTransformKey(key) || isTransformStatusKey(key))
      inputError(path, "frame {}: custom field '{}' would read back as a transform, timestamp or status", index, key);
    out.push_back({index, key, value, 0});
  }
}

// ------------------------------------------------------------------ reader

class SequenceReaderImpl final : public SequenceReader {
public:
  explicit SequenceReaderImpl(const std::string& path) : header_(io::readImageHeader(path)) {
    describe();
    flip_ = checkedFlip(path, header_.orientation);
    groupFrameFields();
    data_ = std::make_unique<io::DataReader>(header_, frameBytes_, info_.frameCount, "frame");
  }

  const SequenceInfo& info() const override { return info_; }

  bool next(Frame& f) override {
    if (next_ == info_.frameCount) {
      if (!ended_) data_->expectEnd();
      ended_ = true;
      return false;
    }
    const std::uint64_t index = next_;
    f.width = info_.width;
    f.height = info_.height;
    f.pixelType = info_.pixelType;
    f.pixels.resize(frameBytes_);
    data_->read(f.pixels.data(), index);
    ++next_;
    if (header_.bigEndian && info_.pixelType == PixelType::U16) swapBytePairs(f.pixels.data(), f.pixels.size());
    if (flip_.any()) flipPixels(f.pixels.data(), f.width, f.height, bytesPerPixel(f.pixelType), flip_);

    const Frame meta = metadata(index);
    f.index = index;
    f.timestamp = meta.timestamp;
    f.imageValid = meta.imageValid;
    f.transforms = meta.transforms;
    f.customFields = meta.customFields;
    return true;
  }

  Frame metadata(std::uint64_t i) const override {
    PP5_CHECK_LT(i, info_.frameCount);
    const auto it = meta_.find(i);
    Frame m = it != meta_.end() ? it->second : Frame{};
    m.index = i;
    m.width = info_.width;
    m.height = info_.height;
    m.pixelType = info_.pixelType;
    return m;
  }

private:
  void describe() {
    const ImageHeader& h = header_;
    const char* sizeKey = h.format == SequenceFormat::MetaIO ? "DimSize" : "sizes";
    if (h.dims.size() < 2 || h.dims.size() > 3)
      inputError(h.path, "{} {} is not a sequence of 2D frames (expected width height frames)", sizeKey,
                 io::dimsText(h.dims));
    if (*h.element != io::ElementType::U8 && *h.element != io::ElementType::U16)
      inputError(h.path, "pixel type {} is not supported for sequences (only uint8 and uint16: MET_UCHAR, MET_USHORT)",
                 io::elementName(*h.element));
    if (h.channels != 1)
      inputError(h.path, "{} channels per pixel: multi-channel (colour) frames are not supported", h.channels);

    info_.path = h.path;
    info_.format = h.format;
    info_.pixelType = *h.element == io::ElementType::U8 ? PixelType::U8 : PixelType::U16;
    info_.frameCount = h.dims.size() == 3 ? static_cast<std::uint64_t>(h.dims[2]) : 1;
    info_.compressed = h.compressed;
    info_.orientation = h.orientation;
    info_.fields = h.fields;

    const std::uint64_t w = static_cast<std::uint64_t>(h.dims[0]), ht = static_cast<std::uint64_t>(h.dims[1]);
    if (info_.frameCount > 0 && (w == 0 || ht == 0))
      inputError(h.path, "{} {} gives frames no pixels", sizeKey, io::dimsText(h.dims));
    // Checked before multiplying, so that the product cannot overflow.
    const std::uint64_t bpp = static_cast<std::uint64_t>(bytesPerPixel(info_.pixelType));
    if (w > kMaxFrameBytes || ht > kMaxFrameBytes || w * ht * bpp > kMaxFrameBytes)
      inputError(h.path, "{} {}: a frame of {}x{} {} pixels is larger than the 1 GiB limit ({} wrong?)", sizeKey,
                 io::dimsText(h.dims), w, ht, io::elementName(*h.element), sizeKey);
    info_.width = static_cast<int>(w);
    info_.height = static_cast<int>(ht);
    frameBytes_ = w * ht * bpp;
  }

  void groupFrameFields() {
    std::map<std::uint64_t, std::vector<const FrameField*>> byFrame;
    for (const auto& f : header_.frameFields) {
      if (f.frame >= info_.frameCount)
        inputErrorAt(header_.path, f.line, "{}{:04d}_{} is for frame {}, but the header declares only {} frames",
                     io::kFramePrefix, f.frame, f.key, f.frame, info_.frameCount);
      byFrame[f.frame].push_back(&f);
    }
    for (const auto& [index, fields] : byFrame) meta_.emplace(index, frameFromFields(header_, index, fields));
    header_.frameFields.clear();
    header_.frameFields.shrink_to_fit();
  }

  ImageHeader header_;
  SequenceInfo info_;
  Flip flip_;
  std::uint64_t frameBytes_ = 0;
  std::map<std::uint64_t, Frame> meta_;  // tracking data by frame; frames without fields have none
  std::unique_ptr<io::DataReader> data_;
  std::uint64_t next_ = 0;
  bool ended_ = false;
};

// ------------------------------------------------------------------ writer

class SequenceWriterImpl final : public SequenceWriter {
public:
  SequenceWriterImpl(const std::string& path, const SequenceWriteOptions& opt)
      : path_(path),
        opt_(opt),
        flip_(checkedFlip(path, opt.orientation)),
        file_(path, opt.compress, opt.compressionLevel) {}

  void write(const Frame& f) override {
    PP5_CHECK(!closed_);
    PP5_CHECK_EQ(f.pixels.size(), f.byteSize());
    if (count_ == 0) {
      first_ = f;
      first_.pixels.clear();
    } else if (f.width != first_.width || f.height != first_.height || f.pixelType != first_.pixelType) {
      inputError(path_, "frame {}: {}x{} with {}-byte pixels differs from the first frame ({}x{}, {}-byte pixels)",
                 count_, f.width, f.height, bytesPerPixel(f.pixelType), first_.width, first_.height,
                 bytesPerPixel(first_.pixelType));
    }
    appendFrameFields(path_, file_.format(), f, count_, fields_);
    if (flip_.any()) {
      scratch_ = f.pixels;
      flipPixels(scratch_.data(), f.width, f.height, bytesPerPixel(f.pixelType), flip_);
      file_.writeData(scratch_.data(), scratch_.size());
    } else {
      file_.writeData(f.pixels.data(), f.pixels.size());
    }
    ++count_;
  }

  void close() override {
    PP5_CHECK(!closed_);
    closed_ = true;
    ImageHeader h;
    h.isSequence = true;
    h.dims = {first_.width, first_.height, static_cast<std::int64_t>(count_)};
    h.element = first_.pixelType == PixelType::U8 ? io::ElementType::U8 : io::ElementType::U16;
    h.kinds = {"domain", "domain", "list"};
    h.orientation = opt_.orientation;
    h.fields = opt_.fields;
    h.frameFields = std::move(fields_);
    file_.finish(std::move(h));
  }

private:
  std::string path_;
  SequenceWriteOptions opt_;
  Flip flip_;
  io::ImageFileWriter file_;
  Frame first_;  // size and pixel type every frame must match
  std::uint64_t count_ = 0;
  std::vector<FrameField> fields_;
  std::vector<std::uint8_t> scratch_;
  bool closed_ = false;
};

}  // namespace

std::unique_ptr<SequenceReader> SequenceReader::open(const std::string& path) {
  if (io::extensionOf(path) == ".journal") return openJournal(path);
  return std::make_unique<SequenceReaderImpl>(path);
}

std::unique_ptr<SequenceWriter> SequenceWriter::create(const std::string& path, const SequenceWriteOptions& opt) {
  return std::make_unique<SequenceWriterImpl>(path, opt);
}

std::vector<Frame> readAllFrames(const std::string& path, SequenceInfo* info) {
  auto reader = SequenceReader::open(path);
  std::vector<Frame> frames;
  Frame f;
  while (reader->next(f)) frames.push_back(f);
  if (info) *info = reader->info();
  return frames;
}

void writeAllFrames(const std::string& path, const std::vector<Frame>& frames, const SequenceWriteOptions& opt) {
  auto writer = SequenceWriter::create(path, opt);
  for (const auto& f : frames) writer->write(f);
  writer->close();
}

ImageFileKind probeImageFile(const std::string& path) {
  if (io::extensionOf(path) == ".journal") return ImageFileKind::Sequence;
  const io::ImageHeader h = io::readImageHeader(path);
  // PLUS's reconstructions carry a stray Seq_Frame0000_ImageStatus, and older
  // ones call their third axis a "list": a spatial third axis decides first,
  // then the presence of per-frame fields.
  const std::string third = h.kinds.size() >= 3 ? io::toLower(h.kinds[2]) : "";
  if (third == "domain" || third == "space") return ImageFileKind::Volume;
  return h.frameFields.empty() ? ImageFileKind::Volume : ImageFileKind::Sequence;
}

}  // namespace pp5
