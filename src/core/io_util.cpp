#include "core/io_util.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <vector>

#include "core/error.hpp"

namespace pp5::io {

namespace {
bool isSpace(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v'; }
// mkstemp makes files readable by their owner only; give the finished file the
// mode an ordinary open() would have. umask can only be read by setting it, so
// this is done once.
mode_t newFileMode() {
  static const mode_t mode = [] {
    const mode_t mask = ::umask(0);
    ::umask(mask);
    return static_cast<mode_t>(0666 & ~mask);
  }();
  return mode;
}
}  // namespace

std::string_view trim(std::string_view s) {
  while (!s.empty() && isSpace(s.front())) s.remove_prefix(1);
  while (!s.empty() && isSpace(s.back())) s.remove_suffix(1);
  return s;
}

std::vector<std::string_view> splitWords(std::string_view s) {
  std::vector<std::string_view> words;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && isSpace(s[i])) ++i;
    const std::size_t start = i;
    while (i < s.size() && !isSpace(s[i])) ++i;
    if (i > start) words.push_back(s.substr(start, i - start));
  }
  return words;
}

std::string toLower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

bool startsWith(std::string_view s, std::string_view prefix) { return s.substr(0, prefix.size()) == prefix; }

bool endsWith(std::string_view s, std::string_view suffix) {
  return s.size() >= suffix.size() && s.substr(s.size() - suffix.size()) == suffix;
}

std::string extensionOf(const std::string& path) { return toLower(std::filesystem::path(path).extension().string()); }

std::optional<double> parseDouble(std::string_view s) {
  s = trim(s);
  // from_chars rejects a leading '+', which some writers emit.
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  double v = 0.0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (s.empty() || ec != std::errc() || end != s.data() + s.size()) return std::nullopt;
  return v;
}

std::optional<std::int64_t> parseInt(std::string_view s) {
  s = trim(s);
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  std::int64_t v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (s.empty() || ec != std::errc() || end != s.data() + s.size()) return std::nullopt;
  return v;
}

std::optional<bool> parseBool(std::string_view s) {
  const std::string v = toLower(trim(s));
  if (v == "true" || v == "1") return true;
  if (v == "false" || v == "0") return false;
  return std::nullopt;
}

std::optional<std::vector<double>> parseDoubles(std::string_view s) {
  std::vector<double> out;
  for (auto w : splitWords(s)) {
    auto v = parseDouble(w);
    if (!v) return std::nullopt;
    out.push_back(*v);
  }
  return out;
}

std::optional<std::vector<std::int64_t>> parseInts(std::string_view s) {
  std::vector<std::int64_t> out;
  for (auto w : splitWords(s)) {
    auto v = parseInt(w);
    if (!v) return std::nullopt;
    out.push_back(*v);
  }
  return out;
}

std::string formatDouble(double v) { return fmt::format("{}", v); }

std::string excerpt(std::string_view s) {
  constexpr std::size_t kMax = 60;
  std::string out;
  for (char c : s.substr(0, kMax)) out += std::isprint(static_cast<unsigned char>(c)) ? c : '?';
  if (s.size() > kMax) out += "...";
  return "'" + out + "'";
}

void checkInputFile(const std::string& path) {
  std::error_code ec;
  const auto st = std::filesystem::status(path, ec);
  if (ec || st.type() == std::filesystem::file_type::not_found || st.type() == std::filesystem::file_type::regular)
    return;
  const char* what = st.type() == std::filesystem::file_type::directory ? "a folder"
                     : st.type() == std::filesystem::file_type::fifo    ? "a FIFO (named pipe)"
                     : st.type() == std::filesystem::file_type::socket  ? "a socket"
                                                                        : "a device or other special file";
  inputError(path, "cannot read: it is {}, not a regular file", what);
}

FilePtr openForReading(const std::string& path) {
  checkInputFile(path);
  FilePtr f(std::fopen(path.c_str(), "rb"));
  if (!f) inputError(path, "cannot open ({})", std::strerror(errno));
  return f;
}

std::uint64_t fileSize(std::FILE* f, const std::string& path) {
  const long here = std::ftell(f);
  if (here < 0 || std::fseek(f, 0, SEEK_END) != 0) inputError(path, "cannot seek ({})", std::strerror(errno));
  const long size = std::ftell(f);
  if (size < 0 || std::fseek(f, here, SEEK_SET) != 0) inputError(path, "cannot seek ({})", std::strerror(errno));
  return static_cast<std::uint64_t>(size);
}

bool readLine(std::FILE* f, std::string& line, const std::string& path, long lineNo, std::size_t maxLength) {
  line.clear();
  int c = 0;
  while ((c = std::getc(f)) != EOF && c != '\n') {
    if (line.size() >= maxLength)
      inputErrorAt(path, lineNo, "header line longer than {} bytes (not a text header, or a missing line break)",
                   maxLength);
    line.push_back(static_cast<char>(c));
  }
  if (std::ferror(f)) inputError(path, "read error ({})", std::strerror(errno));
  if (!line.empty() && line.back() == '\r') line.pop_back();
  return c == '\n' || !line.empty();
}

namespace {
// Hidden and in the same folder, so the final rename is atomic (same file
// system); mkstemp replaces the six X.
constexpr std::string_view kTempSuffix = ".tmp-XXXXXX";
std::string temporaryStem(const std::filesystem::path& finalPath) { return "." + finalPath.filename().string(); }
}  // namespace

bool AtomicFile::isTemporaryOf(const std::string& finalPath, const std::string& fileName) {
  const std::string stem = temporaryStem(finalPath);
  const std::string_view tmp = kTempSuffix.substr(0, kTempSuffix.size() - 6);
  return fileName.size() == stem.size() + kTempSuffix.size() && startsWith(fileName, stem) &&
         std::string_view(fileName).substr(stem.size(), tmp.size()) == tmp;
}

AtomicFile::AtomicFile(std::string finalPath) : finalPath_(std::move(finalPath)) {
  const std::filesystem::path p(finalPath_);
  const std::filesystem::path dir = p.has_parent_path() ? p.parent_path() : std::filesystem::path(".");
  std::string pattern = (dir / (temporaryStem(p) + std::string(kTempSuffix))).string();
  std::vector<char> name(pattern.begin(), pattern.end());
  name.push_back('\0');
  const int fd = ::mkstemp(name.data());
  if (fd < 0) inputError(finalPath_, "cannot create a temporary file in '{}' ({})", dir.string(), std::strerror(errno));
  tempPath_ = name.data();
  ::fchmod(fd, newFileMode());
  file_ = ::fdopen(fd, "w+b");
  if (!file_) {
    ::close(fd);
    std::remove(tempPath_.c_str());
    inputError(finalPath_, "cannot open a temporary file ({})", std::strerror(errno));
  }
}

AtomicFile::~AtomicFile() {
  if (file_) {
    std::fclose(file_);
    std::remove(tempPath_.c_str());
  }
}

void AtomicFile::write(const void* data, std::size_t n) {
  if (n == 0) return;
  if (std::fwrite(data, 1, n, file_) != n) inputError(finalPath_, "write failed ({})", std::strerror(errno));
  written_ += n;
}

void AtomicFile::appendContentsOf(AtomicFile& other) {
  if (std::fflush(other.file_) != 0 || std::fseek(other.file_, 0, SEEK_SET) != 0)
    inputError(finalPath_, "cannot read back temporary data ({})", std::strerror(errno));
  std::vector<char> buf(std::size_t{1} << 20);
  std::uint64_t left = other.written_;
  while (left > 0) {
    const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(left, buf.size()));
    if (std::fread(buf.data(), 1, want, other.file_) != want)
      inputError(finalPath_, "cannot read back temporary data ({})", std::strerror(errno));
    write(buf.data(), want);
    left -= want;
  }
}

bool syncFile(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY);
  if (fd < 0) return false;
  const bool ok = ::fsync(fd) == 0;
  ::close(fd);
  return ok;
}

bool syncFolderOf(const std::string& path) {
  const std::filesystem::path p(path);
  const std::filesystem::path dir = p.has_parent_path() ? p.parent_path() : std::filesystem::path(".");
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return false;
  const bool ok = ::fsync(fd) == 0;
  ::close(fd);
  return ok;
}

void AtomicFile::commit() {
  PP5_CHECK(file_ != nullptr);
  const bool flushed = std::fflush(file_) == 0 && ::fsync(::fileno(file_)) == 0;
  const int err = errno;
  std::fclose(file_);
  file_ = nullptr;
  if (!flushed) {
    std::remove(tempPath_.c_str());
    inputError(finalPath_, "write failed ({})", std::strerror(err));
  }
  if (std::rename(tempPath_.c_str(), finalPath_.c_str()) != 0) {
    const int renameErr = errno;
    std::remove(tempPath_.c_str());
    inputError(finalPath_, "cannot move the finished file into place ({})", std::strerror(renameErr));
  }
  // The new name on disk too, before anything that counts on it (a recording's
  // journal is removed after this); best effort, as not every file system
  // syncs a folder.
  syncFolderOf(finalPath_);
}

void parseListen(const std::string& listen, std::string& address, int& port, const std::string& what) {
  const auto colon = listen.rfind(':');
  address = colon == std::string::npos ? "127.0.0.1" : listen.substr(0, colon);
  const std::string p = colon == std::string::npos ? listen : listen.substr(colon + 1);
  if (address.size() > 2 && address.front() == '[' && address.back() == ']') address = address.substr(1, address.size() - 2);
  char* end = nullptr;
  const long v = std::strtol(p.c_str(), &end, 10);
  if (p.empty() || address.empty() || *end != '\0' || v < 0 || v > 65535)
    throw InputError(fmt::format("{} = \"{}\": give [ADDRESS:]PORT, e.g. 8080 or 127.0.0.1:8080 (port 0..65535)",
                                 what, listen));
  port = static_cast<int>(v);
}


}  // namespace pp5::io
