#pragma once
// Incremental zlib/gzip streams, so that compressed image data is inflated one
// frame at a time and deflated as frames arrive: the whole data block is never
// held in memory.
#include <cstdint>
#include <cstdio>
#include <functional>
#include <memory>
#include <stdexcept>
#include <vector>

namespace pp5::io {

// zlib's own description of what went wrong; callers add the file and frame.
class ZlibError : public std::runtime_error {
public:
  using std::runtime_error::runtime_error;
};
// The input ended before the stream did: a cut-off file rather than bad bytes.
class ZlibTruncated : public ZlibError {
public:
  using ZlibError::ZlibError;
};

// Inflates a zlib or gzip stream (told apart by its header) from the current
// position of `file`, reading at most `compressedBytes` of it.
class Inflater {
public:
  Inflater(std::FILE* file, std::uint64_t compressedBytes);
  ~Inflater();
  Inflater(const Inflater&) = delete;
  Inflater& operator=(const Inflater&) = delete;

  // Fills dst[0, n) and returns n, or fewer when the stream ends first.
  // Throws ZlibError on corrupt data or input that stops mid-stream.
  std::size_t read(std::uint8_t* dst, std::size_t n);
  // Whether the stream has output left (reads ahead one byte to find out, which
  // also makes zlib verify the checksum at the end of the stream).
  bool hasMoreOutput();

private:
  struct State;
  std::unique_ptr<State> s_;
};

// Deflates into `sink` as zlib (MetaIO) or gzip (NRRD) data.
class Deflater {
public:
  using Sink = std::function<void(const std::uint8_t*, std::size_t)>;
  Deflater(Sink sink, int level, bool gzip);
  ~Deflater();
  Deflater(const Deflater&) = delete;
  Deflater& operator=(const Deflater&) = delete;

  void write(const std::uint8_t* data, std::size_t n);
  // Ends the stream; returns the number of compressed bytes in it.
  std::uint64_t finish();

private:
  struct State;
  std::unique_ptr<State> s_;
};

}  // namespace pp5::io
