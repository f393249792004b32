#pragma once
// What the sources share: writing every frame to a PLUS sequence as it
// arrives, and placing a live frame through a device set's chain.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

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

// Records on a thread of its own, so that opening, syncing and closing a
// recording never hold up the caller (the host's pipeline, which hands each
// frame over and goes on). Frames wait in order; once `maxQueuedBytes` of them
// wait, the caller waits for the disk: a frame is never dropped. A recording
// that fails is logged (with where its frames are kept) and its failure is
// `error()`; the frames after it are not written until the next start().
class BackgroundRecorder {
public:
  explicit BackgroundRecorder(std::size_t maxQueuedBytes = std::size_t{64} << 20);
  ~BackgroundRecorder();  // finishes every recording handed to it
  BackgroundRecorder(const BackgroundRecorder&) = delete;
  BackgroundRecorder& operator=(const BackgroundRecorder&) = delete;
  void start(const std::string& path);  // the open recording, if any, is closed first
  void writePlaced(const Frame& f, const Mat4& imageToReference, double timeS);
  void stop();
  // Waits until everything handed over is on disk (and every recording stopped
  // is complete).
  void drain();
  std::string error() const;

private:
  struct Item {
    enum Kind { Start, Write, Stop } kind;
    std::string path;
    Frame frame;
    Mat4 pose{};
    double timeS = 0;
  };
  void run();
  mutable std::mutex m_;
  std::condition_variable cv_;
  std::deque<Item> queue_;
  std::size_t queuedBytes_ = 0, maxQueuedBytes_;
  bool busy_ = false, quit_ = false;
  std::string error_;
  std::thread thread_;
};

// Places a live frame: ImageToReference through the configuration's chain, or
// nullopt (counted, and the first one logged) when the frame cannot be placed.
struct Placer {
  PlusConfig cfg;
  std::atomic<std::uint64_t> unplaced{0};
  std::optional<Mat4> place(const Frame& f);
};

}  // namespace pp5::host
