#pragma once
// Reading and writing the data block of a MetaIO or NRRD image, raw or
// compressed, piece by piece (one frame, or a whole volume). Shared by
// sequence_io.cpp and volume_io.cpp so both formats and both kinds of file
// get the same size checks and error messages.
#include <cstdint>
#include <memory>
#include <string>

#include "formats/image_header.hpp"
#include "core/io_util.hpp"
#include "formats/zstream.hpp"

namespace pp5::io {

class DataReader {
public:
  // Opens the data block and checks its size against the header before
  // anything is allocated: raw data must be exactly `pieceBytes * pieceCount`
  // bytes; compressed data must exist and be able to hold that much.
  // `pieceName` ("frame") names a piece in messages.
  DataReader(const ImageHeader& h, std::uint64_t pieceBytes, std::uint64_t pieceCount, std::string pieceName);
  ~DataReader();

  // Reads piece number `index` (pieces are read in order) into dst.
  void read(std::uint8_t* dst, std::uint64_t index);
  // After the last piece: compressed data must end there too.
  void expectEnd();

private:
  [[noreturn]] void fail(const std::string& what) const;
  void checkRawSize(std::uint64_t available, std::uint64_t total, const std::string& where) const;
  void checkCompressedSize(std::optional<std::uint64_t> declared, std::uint64_t available, std::uint64_t total,
                           const std::string& where) const;

  std::string path_;
  std::string sizeKey_;  // "DimSize" or "sizes": the header field to blame
  std::string shape_;    // "DimSize 820x616x21 of uint8", for messages
  std::uint64_t pieceBytes_;
  std::uint64_t pieceCount_;
  std::string pieceName_;
  FilePtr file_;
  std::unique_ptr<Inflater> inflater_;
};

// Writes header + data. The data streams (compressed or not) into a temporary
// file as it arrives; finish() writes the header, which needs the compressed
// size and every frame's fields, and then moves the files into place at once.
// Abandoned without finish(), it leaves nothing behind.
class ImageFileWriter {
public:
  // Format by extension: .mha (data after the header), .mhd (data in a .raw or
  // .zraw beside it) or .nrrd (data after the header).
  ImageFileWriter(const std::string& path, bool compress, int level);
  // The deflater's sink points back at this object.
  ImageFileWriter(const ImageFileWriter&) = delete;
  ImageFileWriter& operator=(const ImageFileWriter&) = delete;
  SequenceFormat format() const { return format_; }

  void writeData(const std::uint8_t* data, std::size_t n);
  // `h` describes the data; the writer fills in compression and data location.
  void finish(ImageHeader h);

private:
  std::string path_;
  SequenceFormat format_;
  bool compress_;
  std::string detachedName_;  // .mhd: the data file's name beside the header
  std::unique_ptr<AtomicFile> data_;
  std::unique_ptr<Deflater> deflater_;
  bool finished_ = false;
};

// The SequenceFormat a path's extension asks for; InputError otherwise.
SequenceFormat formatFromExtension(const std::string& path);

}  // namespace pp5::io
