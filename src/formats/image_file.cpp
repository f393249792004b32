#include "formats/image_file.hpp"

#include <cctype>
#include <filesystem>
#include <limits>

#include "core/error.hpp"

namespace pp5::io {

int elementBytes(ElementType t) {
  switch (t) {
    case ElementType::U8:
    case ElementType::I8: return 1;
    case ElementType::U16:
    case ElementType::I16: return 2;
    case ElementType::F32: return 4;
    case ElementType::F64: return 8;
  }
  return 1;
}

const char* elementName(ElementType t) {
  switch (t) {
    case ElementType::U8: return "uint8";
    case ElementType::U16: return "uint16";
    case ElementType::I8: return "int8";
    case ElementType::I16: return "int16";
    case ElementType::F32: return "float32";
    case ElementType::F64: return "float64";
  }
  return "?";
}

std::string dimsText(const std::vector<std::int64_t>& dims) {
  std::string out;
  for (std::size_t i = 0; i < dims.size(); ++i) out += (i ? "x" : "") + std::to_string(dims[i]);
  return out;
}

std::optional<std::uint64_t> dataBytes(const ImageHeader& h) {
  if (!h.element || h.channels < 1) return std::nullopt;
  std::uint64_t total = static_cast<std::uint64_t>(elementBytes(*h.element)) * static_cast<std::uint64_t>(h.channels);
  for (std::int64_t d : h.dims) {
    if (d < 0 || __builtin_mul_overflow(total, static_cast<std::uint64_t>(d), &total)) return std::nullopt;
  }
  return total;
}

SequenceFormat formatFromExtension(const std::string& path) {
  const std::string ext = extensionOf(path);
  if (ext == ".mha" || ext == ".mhd") return SequenceFormat::MetaIO;
  if (ext == ".nrrd" || ext == ".nhdr") return SequenceFormat::Nrrd;
  inputError(path, "unknown file type '{}' (expected .mha, .mhd or .nrrd)", ext);
}

ImageHeader readImageHeader(const std::string& path) {
  return formatFromExtension(path) == SequenceFormat::MetaIO ? readMetaHeader(path) : readNrrdHeader(path);
}

void addFrameField(ImageHeader& h, std::string_view key, std::string_view value, long line) {
  const std::string_view rest = key.substr(kFramePrefix.size());
  std::size_t digits = 0;
  while (digits < rest.size() && std::isdigit(static_cast<unsigned char>(rest[digits]))) ++digits;
  // 12 digits keeps the number far from overflow; no recording has that many frames.
  if (digits == 0 || digits > 12 || digits + 1 >= rest.size() || rest[digits] != '_')
    inputErrorAt(h.path, line, "malformed per-frame key {} (expected Seq_FrameNNNN_Name)", excerpt(key));
  const auto frame = parseInt(rest.substr(0, digits));
  h.frameFields.push_back(
      {static_cast<std::uint64_t>(*frame), std::string(rest.substr(digits + 1)), std::string(value), line});
}

void checkHeaderText(const std::string& path, std::string_view key, std::string_view value,
                     std::string_view separator) {
  auto hasBreak = [](std::string_view s) { return s.find_first_of("\r\n") != std::string_view::npos; };
  if (key.empty() || trim(key) != key || hasBreak(key) || key.find(separator) != std::string_view::npos)
    inputError(path, "cannot write header key {}: it must be non-empty, without '{}', line breaks or outer spaces",
               excerpt(key), separator);
  if (trim(value) != value || hasBreak(value))
    inputError(path, "cannot write the value of {}: {} has line breaks or outer spaces, which would not read back", key,
               excerpt(value));
}

std::optional<std::string> detachedDataPath(const std::string& headerPath, std::string_view name) {
  const std::filesystem::path p(std::string{name});
  if (p.empty() || p.is_absolute() || p.has_root_name() || p.has_root_directory()) return std::nullopt;
  for (const auto& part : p)
    if (part == "..") return std::nullopt;
  return (std::filesystem::path(headerPath).parent_path() / p).string();
}

// ---------------------------------------------------------------- DataReader

DataReader::DataReader(const ImageHeader& h, std::uint64_t pieceBytes, std::uint64_t pieceCount, std::string pieceName)
    : path_(h.path), pieceBytes_(pieceBytes), pieceCount_(pieceCount), pieceName_(std::move(pieceName)) {
  sizeKey_ = h.format == SequenceFormat::MetaIO ? "DimSize" : "sizes";
  shape_ = fmt::format("{} {} of {}", sizeKey_, dimsText(h.dims), h.element ? elementName(*h.element) : "?");
  std::uint64_t total = 0;
  if (__builtin_mul_overflow(pieceBytes, pieceCount, &total)) fail(shape_ + " is too large");

  const bool detached = h.dataPath != h.path;
  try {
    file_ = openForReading(h.dataPath);
  } catch (const InputError& e) {
    if (!detached) throw;
    fail(fmt::format("its data file: {}", e.what()));  // name the header that points there
  }
  const std::uint64_t size = fileSize(file_.get(), h.dataPath);
  const std::uint64_t available = size > h.dataOffset ? size - h.dataOffset : 0;
  const std::string where = detached ? "the data in " + h.dataPath : "the data after the header";
  if (h.compressed)
    checkCompressedSize(h.compressedSize, available, total, where);
  else
    checkRawSize(available, total, where);

  if (std::fseek(file_.get(), static_cast<long>(h.dataOffset), SEEK_SET) != 0) fail("cannot seek to the data");
  if (h.compressed) inflater_ = std::make_unique<Inflater>(file_.get(), h.compressedSize.value_or(available));
}

void DataReader::checkRawSize(std::uint64_t available, std::uint64_t total, const std::string& where) const {
  if (available < total) {
    const std::string endsIn =
        pieceCount_ > 1 ? fmt::format(": it ends in {} {}", pieceName_, available / pieceBytes_) : "";
    fail(fmt::format("{} is {} bytes, shorter than the {} that {} needs{} (file truncated, or {} wrong)", where,
                     available, total, shape_, endsIn, sizeKey_));
  }
  if (available > total)
    fail(fmt::format("{} is {} bytes, longer than the {} that {} needs ({} wrong?)", where, available, total, shape_,
                     sizeKey_));
}

void DataReader::checkCompressedSize(std::optional<std::uint64_t> declared, std::uint64_t available,
                                     std::uint64_t total, const std::string& where) const {
  if (declared && *declared > available)
    fail(fmt::format("CompressedDataSize is {} bytes, but {} is only {} (file truncated?)", *declared, where,
                     available));
  const std::uint64_t compressed = declared.value_or(available);
  if (compressed == 0 && total > 0) fail(fmt::format("{} is empty (file truncated?)", where));
  // Deflate cannot do better than about 1032:1, so a larger claim is a wrong
  // size; catching it here keeps an absurd size from reaching an allocation.
  constexpr std::uint64_t kMaxRatio = 1032;
  if (total / kMaxRatio > compressed + 1024)
    fail(fmt::format("{} needs {} bytes, more than {} bytes of compressed data can hold ({} wrong)", shape_, total,
                     compressed, sizeKey_));
}

DataReader::~DataReader() = default;

void DataReader::fail(const std::string& what) const { inputError(path_, "{}", what); }

void DataReader::read(std::uint8_t* dst, std::uint64_t index) {
  const std::string piece = pieceCount_ > 1 ? fmt::format("{} {}: ", pieceName_, index) : "";
  if (!inflater_) {
    // The size was checked on open, so a short read means the file changed under us.
    if (std::fread(dst, 1, pieceBytes_, file_.get()) != pieceBytes_)
      fail(fmt::format("{}read error or unexpected end of the data", piece));
    return;
  }
  std::size_t got = 0;
  try {
    got = inflater_->read(dst, pieceBytes_);
  } catch (const ZlibTruncated& e) {
    fail(fmt::format("{}{} (file truncated?)", piece, e.what()));
  } catch (const ZlibError& e) {
    fail(fmt::format("{}corrupt compressed data ({})", piece, e.what()));
  }
  if (got < pieceBytes_)
    fail(
        fmt::format("{}the compressed data ends {} bytes into this {}, but {} needs {} {}s "
                    "(corrupt or truncated data, or the size is wrong)",
                    piece, got, pieceName_, shape_, pieceCount_, pieceName_));
}

void DataReader::expectEnd() {
  if (!inflater_) return;
  bool more = false;
  try {
    more = inflater_->hasMoreOutput();
  } catch (const ZlibError& e) {
    fail(fmt::format("corrupt compressed data after the last {} ({})", pieceName_, e.what()));
  }
  const std::string pieces = pieceCount_ == 1 ? "" : fmt::format(" the {} {}s that", pieceCount_, pieceName_);
  if (more)
    fail(fmt::format("the compressed data holds more than{} {} needs (corrupt data, or the size is wrong)", pieces,
                     shape_));
}

// ----------------------------------------------------------- ImageFileWriter

ImageFileWriter::ImageFileWriter(const std::string& path, bool compress, int level)
    : path_(path), format_(formatFromExtension(path)), compress_(compress) {
  const std::string ext = extensionOf(path);
  if (ext == ".nhdr") inputError(path, "writing detached NRRD headers (.nhdr) is not supported; use .nrrd");
  std::string dataFinal = path_;
  if (ext == ".mhd") {
    const std::filesystem::path p(path_);
    detachedName_ = p.stem().string() + (compress ? ".zraw" : ".raw");
    dataFinal = (p.parent_path() / detachedName_).string();
  }
  data_ = std::make_unique<AtomicFile>(dataFinal);
  if (compress_)
    deflater_ = std::make_unique<Deflater>([this](const std::uint8_t* p, std::size_t n) { data_->write(p, n); }, level,
                                           format_ == SequenceFormat::Nrrd);
}

void ImageFileWriter::writeData(const std::uint8_t* data, std::size_t n) {
  PP5_CHECK(!finished_);
  if (deflater_)
    deflater_->write(data, n);
  else
    data_->write(data, n);
}

void ImageFileWriter::finish(ImageHeader h) {
  PP5_CHECK(!finished_);
  finished_ = true;
  h.path = path_;
  h.format = format_;
  h.compressed = compress_;
  h.compressedSize = deflater_ ? std::optional<std::uint64_t>(deflater_->finish()) : std::nullopt;
  h.dataPath = detachedName_;
  // Formatting may reject a field; do it before anything is moved into place.
  const std::string header = format_ == SequenceFormat::MetaIO ? formatMetaHeader(h) : formatNrrdHeader(h);
  AtomicFile out(path_);
  out.write(header);
  if (detachedName_.empty()) {
    out.appendContentsOf(*data_);
  } else {
    data_->commit();
  }
  out.commit();
  data_.reset();  // removes the scratch copy of attached data
}

}  // namespace pp5::io
