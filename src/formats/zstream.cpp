#include "formats/zstream.hpp"

#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <limits>
#include <string>

#include "core/error.hpp"

namespace pp5::io {

namespace {
constexpr std::size_t kInputChunk = std::size_t{256} << 10;
// z_stream counts in uInt; larger requests are fed to zlib in pieces.
constexpr std::size_t kMaxZChunk = std::size_t{1} << 30;
// windowBits: 15 for a zlib header, +16 for gzip, +32 to detect either.
constexpr int kWindowBits = 15;

std::string zlibMessage(const z_stream& zs, int ret) {
  if (zs.msg) return zs.msg;
  if (ret == Z_MEM_ERROR) return "out of memory";
  return "zlib error " + std::to_string(ret);
}
}  // namespace

struct Inflater::State {
  z_stream zs{};
  std::FILE* file = nullptr;
  std::uint64_t inputLeft = 0;
  std::vector<std::uint8_t> in;
  bool ended = false;

  void refill() {
    const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(inputLeft, in.size()));
    const std::size_t got = want > 0 ? std::fread(in.data(), 1, want, file) : 0;
    if (got < want && std::ferror(file)) throw ZlibError(std::string("read error: ") + std::strerror(errno));
    inputLeft = got < want ? 0 : inputLeft - got;
    zs.next_in = in.data();
    zs.avail_in = static_cast<uInt>(got);
  }
};

Inflater::Inflater(std::FILE* file, std::uint64_t compressedBytes) : s_(std::make_unique<State>()) {
  s_->file = file;
  s_->inputLeft = compressedBytes;
  s_->in.resize(kInputChunk);
  const int ret = inflateInit2(&s_->zs, kWindowBits + 32);
  if (ret != Z_OK) throw ZlibError(zlibMessage(s_->zs, ret));
}

Inflater::~Inflater() { inflateEnd(&s_->zs); }

std::size_t Inflater::read(std::uint8_t* dst, std::size_t n) {
  z_stream& zs = s_->zs;
  std::size_t done = 0;
  while (done < n && !s_->ended) {
    const std::size_t piece = std::min(n - done, kMaxZChunk);
    zs.next_out = dst + done;
    zs.avail_out = static_cast<uInt>(piece);
    while (zs.avail_out > 0) {
      if (zs.avail_in == 0) s_->refill();
      const bool noInput = zs.avail_in == 0;
      const int ret = inflate(&zs, Z_NO_FLUSH);
      if (ret == Z_STREAM_END) {
        s_->ended = true;
        break;
      }
      // With output space left, "no progress" can only mean the input ran out.
      if (ret == Z_BUF_ERROR && noInput) throw ZlibTruncated("the compressed data stops before the zlib stream ends");
      if (ret != Z_OK && ret != Z_BUF_ERROR) throw ZlibError(zlibMessage(zs, ret));
    }
    done += piece - zs.avail_out;
  }
  return done;
}

bool Inflater::hasMoreOutput() {
  std::uint8_t probe = 0;
  return read(&probe, 1) == 1;
}

struct Deflater::State {
  z_stream zs{};
  Sink sink;
  std::vector<std::uint8_t> out;
  bool finished = false;

  // Runs deflate until zlib has taken all input (or, with Z_FINISH, ended the stream).
  void pump(int flush) {
    for (;;) {
      zs.next_out = out.data();
      zs.avail_out = static_cast<uInt>(out.size());
      const int ret = deflate(&zs, flush);
      if (ret == Z_STREAM_ERROR) throw ZlibError(zlibMessage(zs, ret));
      const std::size_t produced = out.size() - zs.avail_out;
      if (produced > 0) sink(out.data(), produced);
      if (flush == Z_FINISH ? ret == Z_STREAM_END : (zs.avail_in == 0 && zs.avail_out > 0)) return;
    }
  }
};

Deflater::Deflater(Sink sink, int level, bool gzip) : s_(std::make_unique<State>()) {
  s_->sink = std::move(sink);
  s_->out.resize(kInputChunk);
  const int ret =
      deflateInit2(&s_->zs, std::clamp(level, 0, 9), Z_DEFLATED, kWindowBits + (gzip ? 16 : 0), 8, Z_DEFAULT_STRATEGY);
  if (ret != Z_OK) throw ZlibError(zlibMessage(s_->zs, ret));
}

Deflater::~Deflater() { deflateEnd(&s_->zs); }

void Deflater::write(const std::uint8_t* data, std::size_t n) {
  PP5_CHECK(!s_->finished);
  while (n > 0) {
    const std::size_t piece = std::min(n, kMaxZChunk);
    s_->zs.next_in = const_cast<std::uint8_t*>(data);  // zlib's API is not const-correct
    s_->zs.avail_in = static_cast<uInt>(piece);
    s_->pump(Z_NO_FLUSH);
    data += piece;
    n -= piece;
  }
}

std::uint64_t Deflater::finish() {
  if (!s_->finished) {
    s_->zs.next_in = nullptr;
    s_->zs.avail_in = 0;
    s_->pump(Z_FINISH);
    s_->finished = true;
  }
  return s_->zs.total_out;
}

}  // namespace pp5::io
