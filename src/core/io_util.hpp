#pragma once
// Private helpers shared by the MetaIO and NRRD readers and writers: header
// text parsing, opening files with one-line errors, and atomic output files.
#include <cstdint>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace pp5::io {

// ---- header text ----
std::string_view trim(std::string_view s);
std::vector<std::string_view> splitWords(std::string_view s);
std::string toLower(std::string_view s);
bool startsWith(std::string_view s, std::string_view prefix);
bool endsWith(std::string_view s, std::string_view suffix);
// Lower-cased extension including the dot (".mha"); empty when none.
std::string extensionOf(const std::string& path);

// "[ADDR:]PORT" (a server's listen address: the viewer's, the OpenIGTLink
// server's) into its parts, 127.0.0.1 when no address is given and "[::1]"
// unbracketed; InputError naming `what` when malformed.
void parseListen(const std::string& listen, std::string& address, int& port, const std::string& what);
// Whole-token parses: trailing garbage, empty text or overflow give nullopt.
std::optional<double> parseDouble(std::string_view s);
std::optional<std::int64_t> parseInt(std::string_view s);
// "True"/"False" (any case) as MetaIO writes them.
std::optional<bool> parseBool(std::string_view s);
// Whitespace-separated numbers; nullopt when a token is not a number.
std::optional<std::vector<double>> parseDoubles(std::string_view s);
std::optional<std::vector<std::int64_t>> parseInts(std::string_view s);
// Shortest text that reads back as exactly the same double.
std::string formatDouble(double v);
// Quotes a piece of a bad header line for an error message, cut to a readable length.
std::string excerpt(std::string_view s);

// ---- reading files ----
struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};
using FilePtr = std::unique_ptr<std::FILE, FileCloser>;

// InputError unless `path` is a regular file (or a link to one): a folder, a
// FIFO or a device is refused before it is opened, since reading a FIFO
// with no writer would wait forever. A missing file passes (the opener says so).
void checkInputFile(const std::string& path);
// Opens for binary reading (checkInputFile first); InputError "PATH: cannot
// open (reason)" otherwise.
FilePtr openForReading(const std::string& path);
std::uint64_t fileSize(std::FILE* f, const std::string& path);
// Reads one '\n'-terminated line (the '\n' and a '\r' before it are dropped).
// False at end of file. A line longer than maxLength is an InputError, so a
// binary file given by mistake fails quickly instead of filling memory.
bool readLine(std::FILE* f, std::string& line, const std::string& path, long lineNo,
              std::size_t maxLength = std::size_t{1} << 20);

// ---- writing files ----
// fsync of a file written by someone else (a library that closed it): false
// when it cannot be opened or synced.
bool syncFile(const std::string& path);
// fsync of the folder holding `path`, so that a file's new name (a rename, a
// creation) survives a power loss; false when it cannot be done.
bool syncFolderOf(const std::string& path);

// A file written under a temporary name in the folder of its final path.
// commit() renames it into place; destroyed without commit() it removes the
// temporary, so a failed or abandoned write never leaves a partial file under
// the final name and never touches an existing one.
class AtomicFile {
public:
  explicit AtomicFile(std::string finalPath);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  void write(const void* data, std::size_t n);
  void write(std::string_view s) { write(s.data(), s.size()); }
  std::uint64_t bytesWritten() const { return written_; }
  // Appends everything written to `other` so far (used to put a data block,
  // streamed to a scratch file, after a header that could only be written last).
  void appendContentsOf(AtomicFile& other);
  void commit();
  const std::string& finalPath() const { return finalPath_; }
  // Whether `fileName` (in the folder of `finalPath`) is the name of a
  // temporary an AtomicFile for `finalPath` makes: what a killed writer leaves.
  static bool isTemporaryOf(const std::string& finalPath, const std::string& fileName);

private:
  std::string finalPath_;
  std::string tempPath_;
  std::FILE* file_ = nullptr;
  std::uint64_t written_ = 0;
};

}  // namespace pp5::io
