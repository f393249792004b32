#pragma once
// PLUS tracked-frame sequences: MetaIO (.igs.mha, .seq.mha, .mha with
// ElementDataFile = LOCAL; .mhd with .raw/.zraw beside it; CompressedData =
// True as one zlib stream over all frames) and NRRD (.igs.nrrd, .seq.nrrd,
// raw or gzip; custom keys written "key:=value").
//
// Reading is frame by frame: only one frame's pixels are held at a time, so
// long recordings never have to fit in memory. Frames come back in MF
// orientation whatever the file says. All errors are InputError naming the
// file and what is wrong.
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "core/frame.hpp"

namespace pp5 {

enum class SequenceFormat { MetaIO, Nrrd };

struct SequenceInfo {
  std::string path;
  SequenceFormat format = SequenceFormat::MetaIO;
  int width = 0;
  int height = 0;
  PixelType pixelType = PixelType::U8;
  std::uint64_t frameCount = 0;
  bool compressed = false;
  // UltrasoundImageOrientation as in the file ("MF", "MFA", "UF", ...); empty
  // when absent (treated as MF).
  std::string orientation;
  // Global header fields other than the structural ones, in file order
  // (e.g. UltrasoundImageType = BRIGHTNESS).
  std::vector<std::pair<std::string, std::string>> fields;
};

class SequenceReader {
public:
  virtual ~SequenceReader() = default;
  // Opens by extension (.mha/.mhd -> MetaIO, .nrrd -> NRRD; .journal -> the
  // complete frames of a recording that was cut off, recording_journal.hpp)
  // and parses the header; throws InputError on any header problem.
  static std::unique_ptr<SequenceReader> open(const std::string& path);

  virtual const SequenceInfo& info() const = 0;
  // Reads the next frame into `f` (reusing its buffer); false at the end.
  // A short or corrupt data block is an InputError naming the frame.
  virtual bool next(Frame& f) = 0;
  // Frame i's tracking data (index, timestamp, statuses, transforms, custom
  // fields) without its pixels. The header holds every frame's fields, so this
  // needs no data reading: callers can plan (e.g. fit a grid to all poses)
  // before streaming the pixels once.
  virtual Frame metadata(std::uint64_t i) const = 0;
};

struct SequenceWriteOptions {
  bool compress = true;  // zlib (MetaIO) or gzip (NRRD)
  int compressionLevel = 6;
  std::string orientation = "MF";
  // Extra global fields written into the header.
  std::vector<std::pair<std::string, std::string>> fields;
};

class SequenceWriter {
public:
  virtual ~SequenceWriter() = default;
  // Format by extension as for reading. Pixel data is streamed to disk as frames
  // arrive; the header (which PLUS puts before the data) is written on close().
  static std::unique_ptr<SequenceWriter> create(const std::string& path, const SequenceWriteOptions& opt = {});
  // All frames must have the same size and pixel type.
  virtual void write(const Frame& f) = 0;
  // Finishes the file atomically (written under a temporary name, then renamed),
  // so a crash never leaves a half-written sequence under the final name.
  virtual void close() = 0;
};

// What a .mha/.mhd/.nrrd file holds, judged from its header alone: a volume
// when its third axis is of kind "domain" (or "space") or it has no per-frame
// Seq_Frame fields; otherwise a tracked-frame sequence. Used by `pp5echo info`.
enum class ImageFileKind { Sequence, Volume };
ImageFileKind probeImageFile(const std::string& path);

// Convenience: whole file into memory (tests, small files).
std::vector<Frame> readAllFrames(const std::string& path, SequenceInfo* info = nullptr);
void writeAllFrames(const std::string& path, const std::vector<Frame>& frames, const SequenceWriteOptions& opt = {});

}  // namespace pp5
