#pragma once
// Helpers for the I/O tests: reading the PLUS files' header text and data
// independently of the code under test (plain string search, strtod and zlib),
// scratch folders, and running the pp5echo binary.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <zlib.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace pp5::test {

inline std::string dataFile(const std::string& name) { return std::string(PP5_DATA_DIR) + "/" + name; }

inline std::string readBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("test: cannot read " + path);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

inline void writeBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw std::runtime_error("test: cannot write " + path);
}

// A fresh folder, removed with everything in it at the end of the test.
class TempDir {
public:
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name = std::string("pp5io-") + (info ? info->name() : "x") + "-XXXXXX";
    std::string pattern = (std::filesystem::temp_directory_path() / name).string();
    std::vector<char> buf(pattern.begin(), pattern.end());
    buf.push_back('\0');
    if (!::mkdtemp(buf.data())) throw std::runtime_error("test: mkdtemp failed");
    path_ = buf.data();
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  std::string operator/(const std::string& name) const { return path_ + "/" + name; }
  const std::string& path() const { return path_; }
  std::vector<std::string> list() const {
    std::vector<std::string> names;
    for (const auto& e : std::filesystem::directory_iterator(path_)) names.push_back(e.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
  }

private:
  std::string path_;
};

// The header of a PLUS file and where its data starts: MetaIO up to and
// including the "ElementDataFile = LOCAL" line, NRRD up to the blank line.
struct RawFile {
  std::string bytes;
  std::size_t dataStart = 0;
  std::string header() const { return bytes.substr(0, dataStart); }
  std::string data() const { return bytes.substr(dataStart); }
};

inline RawFile splitFile(const std::string& path) {
  RawFile f;
  f.bytes = readBytes(path);
  const bool nrrd = path.size() > 5 && path.substr(path.size() - 5) == ".nrrd";
  const std::string marker = nrrd ? "\n\n" : "ElementDataFile = LOCAL\n";
  const auto pos = f.bytes.find(marker);
  if (pos == std::string::npos) throw std::runtime_error("test: no end of header in " + path);
  f.dataStart = pos + marker.size();
  return f;
}

// The value of "key = value" (MetaIO) or "key:=value" / "key: value" (NRRD) in
// header text, trimmed; empty when absent.
inline std::string headerValue(const std::string& header, const std::string& key) {
  std::istringstream in(header);
  std::string line;
  while (std::getline(in, line)) {
    if (line.compare(0, key.size(), key) != 0) continue;
    std::string rest = line.substr(key.size());
    const auto sep = rest.find_first_not_of(' ');
    if (sep == std::string::npos) continue;
    if (rest.compare(sep, 2, ":=") == 0)
      rest = rest.substr(sep + 2);
    else if (rest[sep] == '=' || rest[sep] == ':')
      rest = rest.substr(sep + 1);
    else
      continue;
    const auto b = rest.find_first_not_of(" \t");
    const auto e = rest.find_last_not_of(" \t\r");
    return b == std::string::npos ? "" : rest.substr(b, e - b + 1);
  }
  return "";
}

inline std::vector<double> numbers(const std::string& text) {
  std::vector<double> out;
  const char* p = text.c_str();
  char* end = nullptr;
  for (;;) {
    while (*p == ' ' || *p == '(' || *p == ')' || *p == ',') ++p;
    if (!*p) break;
    const double v = std::strtod(p, &end);
    if (end == p) throw std::runtime_error("test: not a number in '" + text + "'");
    out.push_back(v);
    p = end;
  }
  return out;
}

// Inflates a whole zlib or gzip blob with zlib directly.
inline std::string inflateAll(const std::string& blob, std::size_t expectedSize) {
  std::string out(expectedSize + 1, '\0');
  z_stream zs{};
  if (inflateInit2(&zs, 15 + 32) != Z_OK) throw std::runtime_error("test: inflateInit2");
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(blob.data()));
  zs.avail_in = static_cast<uInt>(blob.size());
  zs.next_out = reinterpret_cast<Bytef*>(out.data());
  zs.avail_out = static_cast<uInt>(out.size());
  const int ret = inflate(&zs, Z_FINISH);
  const std::size_t produced = out.size() - zs.avail_out;
  inflateEnd(&zs);
  if (ret != Z_STREAM_END) throw std::runtime_error("test: inflate failed");
  out.resize(produced);
  return out;
}

struct CommandResult {
  int exitCode = -1;
  std::string out;
  std::string err;
};

// Runs a shell command line, capturing stdout and stderr separately.
inline CommandResult runCommand(const std::string& command) {
  TempDir dir;
  const std::string errPath = dir / "stderr.txt";
  CommandResult r;
  FILE* pipe = ::popen((command + " 2>'" + errPath + "'").c_str(), "r");
  if (!pipe) throw std::runtime_error("test: popen failed");
  char buf[4096];
  std::size_t n = 0;
  while ((n = std::fread(buf, 1, sizeof buf, pipe)) > 0) r.out.append(buf, n);
  const int status = ::pclose(pipe);
  r.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.err = readBytes(errPath);
  return r;
}

}  // namespace pp5::test
