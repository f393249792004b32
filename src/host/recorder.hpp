#pragma once
// What the sources share: writing every frame to a PLUS sequence as it
// arrives, and placing a live frame through a device set's chain.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "core/frame.hpp"
#include "formats/plus_config.hpp"
#include "formats/recording_journal.hpp"
#include "formats/sequence_io.hpp"
#include "core/transform.hpp"

namespace pp5::host {

// Writes every frame a source produces to `path`, closing the file when the
// source ends (however it ends), so that nothing acquired is lost. Each frame
// goes to the recording's journal first (formats/recording_journal.hpp), so that
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

// Recordings written on a thread of their own, for a caller whose thread
// must not wait for the disk (the host's loop, recording what the viewer's
// page asks for): compressing each frame, the journal's periodic sync and the
// file's close happen there. Frames queue until written (up to
// kMaxQueuedBytes of pixels; beyond, the caller waits), so nothing recorded
// is lost. A frame that cannot be written ends its recording (the journal
// keeps the frames before it) and the error is rethrown on the caller's
// thread once, at its next call (after that call's own work) or by finish().
// A recording that cannot be closed is said in the log, with where its frames
// are kept, as Recorder's destructor says it, and the next one opens all the
// same.
class RecorderThread {
public:
  static constexpr std::size_t kMaxQueuedBytes = std::size_t{256} << 20;
  RecorderThread();
  ~RecorderThread();  // finishes, logging a failure
  RecorderThread(const RecorderThread&) = delete;
  RecorderThread& operator=(const RecorderThread&) = delete;
  // Closes the recording open (if any) and opens `path` ("" = none); nothing
  // when `path` is the one open.
  void record(const std::string& path);
  // Recorder::writePlaced into the recording open, after the frames before it.
  void writePlaced(const Frame& f, const Mat4& imageToReference, double timeS);
  // Closes the recording and waits until everything queued is on disk.
  void finish();
  const std::string& path() const { return path_; }

private:
  struct Job {
    bool isOpen = false;  // an open (or, with `open` empty, a close) rather than a frame
    std::string open;
    std::uint64_t generation = 0;  // an open's: the caller's count of record() changes
    Frame frame;
    Mat4 pose{1.0};
    double timeS = 0.0;
  };
  std::string path_;  // the caller's side: the recording open, and its generation
  std::uint64_t generation_ = 0;
  std::string ended_;  // the caller's recording that failed (record() of it does not reopen it)
  std::mutex m_;
  std::condition_variable cv_, idle_;  // jobs for the thread; the queue shorter or empty
  std::deque<Job> jobs_;
  std::size_t queuedBytes_ = 0;
  bool busy_ = false, quit_ = false;
  std::exception_ptr error_;
  std::uint64_t errorGeneration_ = 0;  // the recording error_ ended
  std::thread thread_;  // last: started once the rest is built
  void push(Job&& j);
  void open(const std::string& path);  // queues the open (or the close, "") and then takes it as the caller's
  std::exception_ptr takeError();
  void run();
};

// Places a live frame: ImageToReference through the configuration's chain, or
// nullopt (counted, and the first one logged) when the frame cannot be placed.
struct Placer {
  PlusConfig cfg;
  std::atomic<std::uint64_t> unplaced{0};
  std::optional<Mat4> place(const Frame& f);
};

}  // namespace pp5::host
