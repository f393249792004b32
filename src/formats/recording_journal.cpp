#include "formats/recording_journal.hpp"

#include <fcntl.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <optional>

#include "core/error.hpp"
#include "formats/image_file.hpp"
#include "core/io_util.hpp"

namespace pp5 {

namespace {

namespace fs = std::filesystem;

constexpr std::string_view kFirstLine = "PP5ECHO RECORDING JOURNAL 1";
constexpr std::string_view kEndLine = "End";
constexpr char kMagic[4] = {'P', 'P', '5', 'F'};
constexpr std::size_t kPreludeBytes = 16;  // magic, CRC-32 of the body, body length
// A body larger than this is damage, not a frame (frames are at most 1 GiB).
constexpr std::uint64_t kMaxBodyBytes = (std::uint64_t{1} << 30) + (std::uint64_t{1} << 24);
constexpr double kSyncIntervalS = 1.0;
constexpr std::uint64_t kMaxTransforms = 256;
constexpr std::uint64_t kMaxCustomFields = 4096;

double nowS() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// ---- little-endian packing of a record's body ----

void storeLE(std::uint8_t* p, std::uint64_t v, int bytes) {
  for (int i = 0; i < bytes; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
void putLE(std::vector<std::uint8_t>& b, std::uint64_t v, int bytes) {
  b.resize(b.size() + static_cast<std::size_t>(bytes));
  storeLE(b.data() + b.size() - static_cast<std::size_t>(bytes), v, bytes);
}
void putU32(std::vector<std::uint8_t>& b, std::uint32_t v) { putLE(b, v, 4); }
void putU64(std::vector<std::uint8_t>& b, std::uint64_t v) { putLE(b, v, 8); }
void putF64(std::vector<std::uint8_t>& b, double v) { putU64(b, std::bit_cast<std::uint64_t>(v)); }
void putText(std::vector<std::uint8_t>& b, const std::string& s) {
  putU32(b, static_cast<std::uint32_t>(s.size()));
  b.insert(b.end(), s.begin(), s.end());
}

// Reads a body back; every read is bounds-checked, so damage that passed the
// CRC (it cannot, short of a forged record) still only fails the record.
class Unpacker {
public:
  Unpacker(const std::uint8_t* p, std::size_t n) : p_(p), n_(n) {}
  bool ok() const { return ok_; }
  std::size_t remaining() const { return n_ - at_; }
  std::size_t at() const { return at_; }
  std::uint64_t u(int bytes) {
    if (!take(static_cast<std::size_t>(bytes))) return 0;
    std::uint64_t v = 0;
    for (int i = 0; i < bytes; ++i) v |= std::uint64_t{p_[at_ - static_cast<std::size_t>(bytes) + static_cast<std::size_t>(i)]} << (8 * i);
    return v;
  }
  double f64() { return std::bit_cast<double>(u(8)); }
  std::string text() {
    const std::size_t len = static_cast<std::size_t>(u(4));
    if (!take(len)) return {};
    return std::string(reinterpret_cast<const char*>(p_ + at_ - len), len);
  }

private:
  bool take(std::size_t k) {
    if (!ok_ || k > n_ - at_) {
      ok_ = false;
      return false;
    }
    at_ += k;
    return true;
  }
  const std::uint8_t* p_;
  std::size_t n_;
  std::size_t at_ = 0;
  bool ok_ = true;
};

// The body: the frame's tracking data, then its pixels (the rest of the body).
void packFrame(const Frame& f, std::vector<std::uint8_t>& b) {
  putU64(b, f.index);
  putF64(b, f.timestamp);
  b.push_back(f.imageValid ? 1 : 0);
  putU32(b, static_cast<std::uint32_t>(f.width));
  putU32(b, static_cast<std::uint32_t>(f.height));
  b.push_back(static_cast<std::uint8_t>(f.pixelType));
  putU32(b, static_cast<std::uint32_t>(f.transforms.size()));
  for (const auto& t : f.transforms) {
    putText(b, t.name);
    for (double v : toRowMajor(t.matrix)) putF64(b, v);
    b.push_back(t.valid ? 1 : 0);
  }
  putU32(b, static_cast<std::uint32_t>(f.customFields.size()));
  for (const auto& [k, v] : f.customFields) {
    putText(b, k);
    putText(b, v);
  }
  b.insert(b.end(), f.pixels.begin(), f.pixels.end());
}

// Unpacks everything but the pixels; returns the pixels' offset in the body,
// or a reason the body is not a frame.
std::optional<std::size_t> unpackFrameMeta(const std::uint8_t* p, std::size_t n, Frame& f, std::string& why) {
  Unpacker u(p, n);
  f.index = u.u(8);
  f.timestamp = u.f64();
  f.imageValid = u.u(1) != 0;
  const std::uint64_t w = u.u(4), h = u.u(4), type = u.u(1);
  // Bounded, so that a record of tiny entries cannot cost memory many times
  // its size (a PLUS frame has a handful of each).
  const std::uint64_t nt = u.u(4);
  if (nt > kMaxTransforms) {
    why = fmt::format("it claims {} transforms (at most {})", nt, kMaxTransforms);
    return std::nullopt;
  }
  f.transforms.clear();
  for (std::uint64_t i = 0; u.ok() && i < nt; ++i) {
    FrameTransform t;
    t.name = u.text();
    std::array<double, 16> m{};
    for (double& v : m) v = u.f64();
    t.matrix = fromRowMajor(m);
    t.valid = u.u(1) != 0;
    f.transforms.push_back(std::move(t));
  }
  const std::uint64_t nc = u.u(4);
  if (nc > kMaxCustomFields) {
    why = fmt::format("it claims {} custom fields (at most {})", nc, kMaxCustomFields);
    return std::nullopt;
  }
  f.customFields.clear();
  for (std::uint64_t i = 0; u.ok() && i < nc; ++i) {
    std::string k = u.text();
    f.customFields.emplace_back(std::move(k), u.text());
  }
  if (!u.ok()) {
    why = "its tracking data runs past its end";
    return std::nullopt;
  }
  if (type > 1 || w == 0 || h == 0 || w > (1u << 20) || h > (1u << 20)) {
    why = fmt::format("it describes no frame ({}x{} of pixel type {})", w, h, type);
    return std::nullopt;
  }
  f.width = static_cast<int>(w);
  f.height = static_cast<int>(h);
  f.pixelType = type == 0 ? PixelType::U8 : PixelType::U16;
  if (u.remaining() != f.byteSize()) {
    why = fmt::format("it holds {} bytes of pixels where {}x{} needs {}", u.remaining(), w, h, f.byteSize());
    return std::nullopt;
  }
  return u.at();
}

std::uint32_t crcOf(const std::uint8_t* p, std::size_t n) {
  uLong c = crc32(0L, Z_NULL, 0);
  while (n > 0) {  // zlib's length is a uInt
    const uInt k = static_cast<uInt>(std::min<std::size_t>(n, std::size_t{1} << 30));
    c = crc32(c, p, k);
    p += k;
    n -= k;
  }
  return static_cast<std::uint32_t>(c);
}

void writeAll(int fd, const std::uint8_t* p, std::size_t n, const std::string& path) {
  while (n > 0) {
    const ssize_t k = ::write(fd, p, n);
    if (k < 0) {
      if (errno == EINTR) continue;
      inputError(path, "write failed ({})", std::strerror(errno));
    }
    if (k == 0) inputError(path, "write failed (no progress)");
    p += k;
    n -= static_cast<std::size_t>(k);
  }
}

std::string optionsHeader(const std::string& sequencePath, const SequenceWriteOptions& opt) {
  std::string h = std::string(kFirstLine) + "\n";
  h += fmt::format("Sequence = {}\n", fs::path(sequencePath).filename().string());
  h += fmt::format("Compress = {}\n", opt.compress ? 1 : 0);
  h += fmt::format("CompressionLevel = {}\n", opt.compressionLevel);
  h += fmt::format("Orientation = {}\n", opt.orientation);
  for (const auto& [k, v] : opt.fields) {
    if (k.find_first_of("=\n") != std::string::npos || v.find('\n') != std::string::npos)
      inputError(sequencePath, "header field '{}' cannot be journalled (a '=' or line break in it)", k);
    h += fmt::format("Field {} = {}\n", k, v);
  }
  h += std::string(kEndLine) + "\n";
  return h;
}

// ---------------------------------------------------------------- reader

class JournalReaderImpl final : public SequenceReader {
public:
  explicit JournalReaderImpl(const std::string& path) : file_(io::openForReading(path)) {
    c_.path = path;
    c_.fileBytes = io::fileSize(file_.get(), path);
    readHeader();
    scanRecords();
    info_.path = path;
    info_.format = io::formatFromExtension(c_.sequencePath);
    info_.frameCount = c_.frames;
    info_.compressed = false;
    info_.orientation = "MF";  // frames are journalled as they are held
    info_.fields = c_.options.fields;
    if (!meta_.empty()) {
      info_.width = meta_.front().width;
      info_.height = meta_.front().height;
      info_.pixelType = meta_.front().pixelType;
    }
  }

  const JournalContents& contents() const { return c_; }
  const SequenceInfo& info() const override { return info_; }

  bool next(Frame& f) override {
    if (next_ == meta_.size()) return false;
    std::vector<std::uint8_t> buffer = std::move(f.pixels);  // reused, as the other readers do
    f = meta_[next_];
    f.pixels = std::move(buffer);
    f.pixels.resize(f.byteSize());
    if (std::fseek(file_.get(), static_cast<long>(pixelsAt_[next_]), SEEK_SET) != 0 ||
        std::fread(f.pixels.data(), 1, f.pixels.size(), file_.get()) != f.pixels.size())
      inputError(c_.path, "frame {}: cannot read its pixels again (the file changed while it was read?)", next_);
    ++next_;
    return true;
  }

  Frame metadata(std::uint64_t i) const override {
    PP5_CHECK_LT(i, meta_.size());
    return meta_[i];
  }

private:
  void readHeader() {
    std::string line;
    long lineNo = 0;
    auto nextLine = [&] {
      if (!io::readLine(file_.get(), line, c_.path, ++lineNo, 4096))
        inputError(c_.path, "the journal's header ends before its '{}' line", kEndLine);
      return std::string_view(line);
    };
    if (!io::readLine(file_.get(), line, c_.path, ++lineNo, 4096) || line != kFirstLine)
      inputError(c_.path, "not a pp5echo recording journal (its first line is not '{}')", kFirstLine);
    for (std::string_view l = nextLine(); l != kEndLine; l = nextLine()) {
      const bool field = io::startsWith(l, "Field ");
      if (field) l.remove_prefix(6);
      const auto eq = l.find('=');
      if (eq == std::string_view::npos) inputErrorAt(c_.path, lineNo, "expected 'key = value': {}", io::excerpt(l));
      const std::string key(io::trim(l.substr(0, eq)));
      const std::string value(io::trim(l.substr(eq + 1)));
      if (field) {
        c_.options.fields.emplace_back(key, value);
      } else if (key == "Sequence") {
        if (value.empty() || value.find('/') != std::string::npos)
          inputErrorAt(c_.path, lineNo, "Sequence must be a file name: {}", io::excerpt(value));
        const fs::path dir = fs::path(c_.path).parent_path();
        c_.sequencePath = (dir / value).string();
      } else if (key == "Compress") {
        c_.options.compress = value == "1";
      } else if (key == "CompressionLevel") {
        const auto v = io::parseInt(value);
        if (!v || *v < 0 || *v > 9) inputErrorAt(c_.path, lineNo, "CompressionLevel {} is not 0 to 9", io::excerpt(value));
        c_.options.compressionLevel = static_cast<int>(*v);
      } else if (key == "Orientation") {
        c_.options.orientation = value;
      } else {
        inputErrorAt(c_.path, lineNo, "unknown key '{}'", io::excerpt(key));
      }
    }
    if (c_.sequencePath.empty()) inputError(c_.path, "the journal's header names no Sequence");
    io::formatFromExtension(c_.sequencePath);  // a name the writer could have had
    // A journal belongs to the sequence its own name says (it may have been
    // moved away from the one it was written for, and that one recorded again).
    const std::string own = c_.path.substr(0, c_.path.size() - std::string_view(".journal").size());
    if (io::endsWith(c_.path, ".journal") && !own.empty() && io::extensionOf(own) != "" && [&] {
          try {
            io::formatFromExtension(own);
            return true;
          } catch (const InputError&) {
            return false;
          }
        }())
      c_.sequencePath = own;
    const long at = std::ftell(file_.get());
    c_.keptBytes = at < 0 ? 0 : static_cast<std::uint64_t>(at);
  }

  // Every record that reads whole, in order. A damaged one (or several in a
  // row) costs only itself: the scan resumes at the next record that reads
  // whole (its magic, a length inside the file and a matching checksum). A
  // record that nothing whole follows is where the journal was cut off.
  void scanRecords() {
    std::vector<std::uint8_t> body;
    std::uint64_t at = c_.keptBytes;
    for (std::uint64_t n = 0;; ++n) {
      std::string why;
      bool cutOff = false;
      const auto end = readRecord(at, body, why, cutOff);
      if (end == at) return;  // the end of the file, after a whole record
      if (end) {
        at = *end;
        continue;
      }
      const auto resume = nextWholeRecord(at + 1);
      if (!resume) {
        c_.cut = fmt::format("frame {}: {}", n, why);
        c_.truncated = cutOff;
        return;
      }
      c_.damaged.push_back(fmt::format("frame {} (bytes {} to {}): {}", n, at, *resume, why));
      c_.damagedBytes += *resume - at;
      at = *resume;
      // The frames after it are whole; `n` counts the lost one as one frame.
    }
  }

  // The record at byte `at`, checked whole: its end (`at` itself at the end
  // of the file), or none with `why` (and `cutOff` when the file ends inside
  // it). A whole record is kept unless `keep` is false.
  std::optional<std::uint64_t> readRecord(std::uint64_t at, std::vector<std::uint8_t>& body,
                                          std::string& why, bool& cutOff, bool keep = true) {
    if (std::fseek(file_.get(), static_cast<long>(at), SEEK_SET) != 0) {
      why = "cannot seek in the file";
      return std::nullopt;
    }
    std::uint8_t prelude[kPreludeBytes];
    const std::size_t got = std::fread(prelude, 1, kPreludeBytes, file_.get());
    if (got == 0) return at;
    auto stop = [&](std::string text, bool cut = false) -> std::optional<std::uint64_t> {
      why = std::move(text);
      cutOff = cut;
      return std::nullopt;
    };
    if (got < kPreludeBytes) return stop("the record is cut off in its first bytes", true);
    if (std::memcmp(prelude, kMagic, 4) != 0) return stop("the record does not start as one (damaged)");
    Unpacker u(prelude + 4, kPreludeBytes - 4);
    const auto crc = static_cast<std::uint32_t>(u.u(4));
    const std::uint64_t bytes = u.u(8);
    if (bytes > kMaxBodyBytes) return stop(fmt::format("the record claims {} bytes (damaged)", bytes));
    // Checked against the file before anything is allocated (a damaged
    // length must not cost a gigabyte; found by fuzz_journal).
    const std::uint64_t available = c_.fileBytes - std::min(c_.fileBytes, at + kPreludeBytes);
    if (bytes > available) return stop(fmt::format("the record is cut off ({} of its {} bytes)", available, bytes), true);
    body.resize(static_cast<std::size_t>(bytes));
    if (std::fread(body.data(), 1, body.size(), file_.get()) != body.size())
      return stop("the record could not be read (the file shrank while it was read?)");
    if (crcOf(body.data(), body.size()) != crc) return stop("the record fails its checksum (damaged)");
    Frame m;
    const auto pixels = unpackFrameMeta(body.data(), body.size(), m, why);
    if (!pixels) return std::nullopt;
    if (!meta_.empty() && (m.width != meta_.front().width || m.height != meta_.front().height ||
                           m.pixelType != meta_.front().pixelType))
      return stop(fmt::format("{}x{} differs from the first frame's {}x{}", m.width, m.height, meta_.front().width,
                              meta_.front().height));
    const std::uint64_t end = at + kPreludeBytes + bytes;
    if (keep) {
      meta_.push_back(std::move(m));
      pixelsAt_.push_back(at + kPreludeBytes + *pixels);
      c_.frames = meta_.size();
      c_.keptBytes = end;
    }
    return end;
  }

  // The first byte from `from` on where a whole record starts, or none.
  std::optional<std::uint64_t> nextWholeRecord(std::uint64_t from) {
    constexpr std::size_t kChunk = std::size_t{1} << 20;
    std::vector<std::uint8_t> chunk(kChunk + 3), body;
    for (std::uint64_t base = from; base + 4 <= c_.fileBytes; base += kChunk) {
      const auto n = static_cast<std::size_t>(std::min<std::uint64_t>(kChunk + 3, c_.fileBytes - base));
      if (std::fseek(file_.get(), static_cast<long>(base), SEEK_SET) != 0 ||
          std::fread(chunk.data(), 1, n, file_.get()) != n)
        return std::nullopt;
      for (std::size_t i = 0; i + 4 <= n && i < kChunk; ++i) {
        const void* hit = std::memchr(chunk.data() + i, kMagic[0], std::min(n - 3, kChunk) - i);
        if (!hit) break;
        i = static_cast<std::size_t>(static_cast<const std::uint8_t*>(hit) - chunk.data());
        if (std::memcmp(chunk.data() + i, kMagic, 4) != 0) continue;
        std::string why;
        bool cutOff = false;
        const std::uint64_t at = base + i;
        if (const auto end = readRecord(at, body, why, cutOff, false); end && *end != at) return at;
      }
    }
    return std::nullopt;
  }

  io::FilePtr file_;
  JournalContents c_;
  SequenceInfo info_;
  std::vector<Frame> meta_;  // without pixels
  std::vector<std::uint64_t> pixelsAt_;
  std::size_t next_ = 0;
};

}  // namespace

std::string journalPathFor(const std::string& sequencePath) { return sequencePath + ".journal"; }

namespace {
[[noreturn]] void leftJournal(const std::string& journal) {
  inputError(journal, "a recording that was cut off is still in this journal; restore it first "
                      "(pp5echo restore {}) or move it away",
             journal);
}
}  // namespace

void checkRecordingTarget(const std::string& sequencePath) {
  io::formatFromExtension(sequencePath);
  const fs::path p(sequencePath);
  const fs::path dir = p.has_parent_path() ? p.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) inputError(sequencePath, "the recording's folder '{}' does not exist", dir.string());
  if (fs::exists(journalPathFor(sequencePath), ec)) leftJournal(journalPathFor(sequencePath));
}

JournalWriter::JournalWriter(const std::string& sequencePath, const SequenceWriteOptions& opt)
    : path_(journalPathFor(sequencePath)) {
  io::formatFromExtension(sequencePath);
  const std::string header = optionsHeader(sequencePath, opt);
  fd_ = ::open(path_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_APPEND | O_CLOEXEC, 0666);
  if (fd_ < 0) {
    if (errno == EEXIST) leftJournal(path_);
    inputError(path_, "cannot create the recording's journal ({})", std::strerror(errno));
  }
  try {
    writeAll(fd_, reinterpret_cast<const std::uint8_t*>(header.data()), header.size(), path_);
    sync();
  } catch (const InputError&) {
    ::close(fd_);  // a journal without its header would only be in the next recording's way
    fd_ = -1;
    std::remove(path_.c_str());
    throw;
  }
  io::syncFolderOf(path_);  // the journal's name must survive too
}

JournalWriter::~JournalWriter() {
  if (fd_ >= 0) ::close(fd_);
}

void JournalWriter::append(const Frame& f) {
  PP5_CHECK(fd_ >= 0);
  PP5_CHECK_EQ(f.pixels.size(), f.byteSize());
  // What a reader would refuse is not written (a live source may send anything).
  if (f.transforms.size() > kMaxTransforms || f.customFields.size() > kMaxCustomFields)
    inputError(path_, "frame {}: {} transforms and {} custom fields; a recording holds at most {} and {} per frame",
               f.index, f.transforms.size(), f.customFields.size(), kMaxTransforms, kMaxCustomFields);
  std::vector<std::uint8_t>& rec = record_;  // reused: a frame's worth, every frame
  rec.assign(kPreludeBytes, 0);
  packFrame(f, rec);
  const std::uint64_t bodyBytes = rec.size() - kPreludeBytes;
  std::memcpy(rec.data(), kMagic, 4);
  storeLE(rec.data() + 4, crcOf(rec.data() + kPreludeBytes, bodyBytes), 4);
  storeLE(rec.data() + 8, bodyBytes, 8);
  writeAll(fd_, rec.data(), rec.size(), path_);  // one write(2) for the whole record
  ++frames_;
  if (nowS() - lastSyncS_ >= kSyncIntervalS) sync();
}

void JournalWriter::sync() {
  if (::fdatasync(fd_) != 0)
    inputError(path_, "cannot make the journal safe on disk (fdatasync: {})", std::strerror(errno));
  lastSyncS_ = nowS();
}

void JournalWriter::discard() {
  if (fd_ < 0) return;
  ::close(fd_);
  fd_ = -1;
  std::error_code ec;
  fs::remove(path_, ec);
}

std::unique_ptr<SequenceReader> openJournal(const std::string& path, JournalContents* contents) {
  auto r = std::make_unique<JournalReaderImpl>(path);
  if (contents) *contents = r->contents();
  return r;
}

RestoreResult restoreJournal(const std::string& journalPath, std::string outPath,
                             const std::function<void(std::uint64_t, std::uint64_t)>& progress) {
  RestoreResult res;
  auto reader = openJournal(journalPath, &res.contents);
  const JournalContents& c = res.contents;
  const bool toItsSequence = outPath.empty() || fs::absolute(outPath).lexically_normal() ==
                                                    fs::absolute(c.sequencePath).lexically_normal();
  res.outPath = outPath.empty() ? c.sequencePath : outPath;
  if (c.frames == 0) {
    // Cut off before its first frame was whole: nothing was recorded. A first
    // record that is damaged (not cut) may hide whole ones after it: kept.
    if (!toItsSequence || !(c.cut.empty() || c.truncated))
      inputError(journalPath, "holds no complete frame{}; there is nothing to restore{}",
                 c.cut.empty() ? std::string() : " (" + c.cut + ")",
                 c.cut.empty() || c.truncated ? "" : ", and the journal is kept as it is");
    reader.reset();
    fs::remove(journalPath);
    res.outPath.clear();
    return res;
  }
  std::error_code ec;
  if (toItsSequence && fs::exists(res.outPath, ec))
    inputError(res.outPath, "exists already; restore {} elsewhere with -o, or move {} away first", journalPath,
               res.outPath);
  auto writer = SequenceWriter::create(res.outPath, c.options);
  Frame f;
  std::uint64_t done = 0;
  while (reader->next(f)) {
    writer->write(f);
    if (progress) progress(++done, c.frames);
  }
  writer->close();
  reader.reset();
  if (!toItsSequence) return res;
  // Damaged records were left out: the journal stays, for the user to look
  // at (or to try again) before removing it.
  if (!c.damaged.empty()) return res;
  // The sequence is whole again (its name on disk: AtomicFile synced the
  // folder): the journal and what the killed writer left half-written beside
  // it (its temporaries, never under a final name) go.
  fs::remove(journalPath);
  const fs::path seq(c.sequencePath);
  const fs::path dir = seq.has_parent_path() ? seq.parent_path() : fs::path(".");
  // The header's file, and a .mhd's data file beside it.
  const std::string stem = (dir / seq.stem()).string();
  const std::vector<std::string> finals = {c.sequencePath, stem + ".raw", stem + ".zraw"};
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    for (const auto& f : finals)
      if (io::AtomicFile::isTemporaryOf(f, name) && e.is_regular_file(ec)) {
        fs::remove(e.path(), ec);
        ++res.leftoverTemporaries;
      }
  }
  return res;
}

}  // namespace pp5
