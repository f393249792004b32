#pragma once
// What the sources share: writing every frame to a PLUS sequence as it
// arrives, and placing a live frame through a device set's chain.
#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "core/frame.hpp"
#include "core/plus_config.hpp"
#include "core/recording_journal.hpp"
#include "core/sequence_io.hpp"
#include "core/transform.hpp"

namespace pp5::host {

// Writes every frame a source produces to `path`, closing the file when the
// source ends (however it ends), so that nothing acquired is lost. Each frame
// goes to the recording's journal first (core/recording_journal.hpp), so that
// a process killed in the middle keeps every frame it had: `pp5echo restore`
// makes the sequence from it. An empty path writes nothing.
class Recorder {
public:
  explicit Recorder(const std::string& path) : path_(path) {}
  ~Recorder();
  Recorder(const Recorder&) = delete;
  Recorder& operator=(const Recorder&) = delete;
  void write(const Frame& f);
  // A frame as it went into the pipeline: with its ImageToReference (replacing
  // any it had), so that the file replays without a device-set configuration.
  void writePlaced(const Frame& f, const Mat4& imageToReference, double timeS);
  void close();

private:
  std::string path_;
  std::unique_ptr<JournalWriter> journal_;
  std::unique_ptr<SequenceWriter> w_;
  std::uint64_t frames_ = 0;
  bool failed_ = false;  // a frame could not be written to the sequence
};

// Places a live frame: ImageToReference through the configuration's chain, or
// nullopt (counted, and the first one logged) when the frame cannot be placed.
struct Placer {
  PlusConfig cfg;
  std::atomic<std::uint64_t> unplaced{0};
  std::optional<Mat4> place(const Frame& f);
};

}  // namespace pp5::host
