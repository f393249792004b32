#include "host/recorder.hpp"

#include <spdlog/spdlog.h>

#include "core/error.hpp"

#include "host/sources.hpp"

namespace pp5::host {

Recorder::~Recorder() {
  try {
    close();
  } catch (const std::exception& e) {
    spdlog::error("run.record: {}: {}", path_, e.what());
  }
}

void Recorder::write(const Frame& f) {
  if (path_.empty()) return;
  if (failed_) return;  // the journal keeps what came before; the run is failing
  if (!w_) {
    // The sequence first: a journal is only made for a recording that can start.
    auto w = SequenceWriter::create(path_);
    journal_ = std::make_unique<JournalWriter>(path_, SequenceWriteOptions{});
    w_ = std::move(w);
  }
  journal_->append(f);
  try {
    w_->write(f);
  } catch (...) {
    // The sequence may be half-written: abandoned, and the journal kept.
    failed_ = true;
    w_.reset();
    throw;
  }
  ++frames_;
}

void Recorder::writePlaced(const Frame& f, const Mat4& imageToReference, double timeS) {
  Frame placed = f;
  placed.timestamp = timeS;
  std::erase_if(placed.transforms, [](const FrameTransform& t) { return t.name == "ImageToReference"; });
  placed.transforms.push_back({"ImageToReference", imageToReference, true});
  write(placed);
}

void Recorder::close() {
  if (failed_ && journal_) {
    spdlog::error("run.record: {} could not be written; every frame recorded is kept in {} (pp5echo restore {})",
                  path_, journal_->path(), journal_->path());
    journal_.reset();
    return;
  }
  if (!w_) return;
  auto w = std::move(w_);
  try {
    w->close();
  } catch (const std::exception& e) {
    throw InputError(fmt::format("{} (the {} frames recorded are kept in {}: pp5echo restore {})", e.what(), frames_,
                                 journal_->path(), journal_->path()));
  }
  journal_->discard();
  spdlog::info("run.record: {} frames written to {}", frames_, path_);
}

namespace {

// A recording's failure that will not be rethrown, said in the log.
void logFailure(const std::exception_ptr& e) {
  try {
    std::rethrow_exception(e);
  } catch (const std::exception& x) {
    spdlog::error("viewer: the page's recording: {}", x.what());
  } catch (...) {
    spdlog::error("viewer: the page's recording failed (an unknown error)");
  }
}

// A call's own work first (a failure of an earlier recording must not cost
// the one open a frame), then the writer's failure `e`, if any; when the work
// itself throws, `e` is said in the log so that it is not lost.
template <class F>
void workThenSay(const std::exception_ptr& e, F&& work) {
  try {
    work();
  } catch (...) {
    if (e) logFailure(e);
    throw;
  }
  if (e) std::rethrow_exception(e);
}

}  // namespace

RecorderThread::RecorderThread() : thread_([this] { run(); }) {}

RecorderThread::~RecorderThread() {
  try {
    finish();
  } catch (...) {
    logFailure(std::current_exception());
  }
  {
    const std::lock_guard lock(m_);
    quit_ = true;
  }
  cv_.notify_one();
  thread_.join();
}

std::exception_ptr RecorderThread::takeError() {
  std::exception_ptr e;
  std::uint64_t failed = 0;
  {
    const std::lock_guard lock(m_);
    std::swap(e, error_);
    failed = errorGeneration_;
  }
  // The caller's recording is the one that failed: it is over (its frames
  // are in its journal). An earlier one's failure leaves the caller's alone.
  if (e && failed == generation_) {
    ended_ = path_;  // not opened again by the caller's next record() of it
    path_.clear();
  }
  return e;
}

void RecorderThread::push(Job&& j) {
  const std::size_t bytes = j.frame.pixels.size();
  std::unique_lock lock(m_);
  // A writer that cannot keep up holds the caller back rather than taking
  // memory without bound (one frame may always wait).
  idle_.wait(lock, [&] { return queuedBytes_ == 0 || queuedBytes_ + bytes <= kMaxQueuedBytes; });
  queuedBytes_ += bytes;
  jobs_.push_back(std::move(j));
  lock.unlock();
  cv_.notify_one();
}

void RecorderThread::open(const std::string& path) {
  Job j;
  j.isOpen = true;
  j.open = path;
  j.generation = generation_ + 1;
  push(std::move(j));
  path_ = path;  // only once the writer has it
  ++generation_;
}

void RecorderThread::record(const std::string& path) {
  workThenSay(takeError(), [&] {
    if (path == path_ || (!path.empty() && path == ended_)) return;  // the one open, or the one that failed
    ended_.clear();
    open(path);
  });
}

void RecorderThread::writePlaced(const Frame& f, const Mat4& imageToReference, double timeS) {
  workThenSay(takeError(), [&] {
    if (path_.empty()) return;
    Job j;
    j.frame = f;
    j.pose = imageToReference;
    j.timeS = timeS;
    push(std::move(j));
  });
}

void RecorderThread::finish() {
  if (!path_.empty()) open("");
  {
    std::unique_lock lock(m_);
    idle_.wait(lock, [&] { return jobs_.empty() && !busy_; });
  }
  if (const std::exception_ptr e = takeError()) std::rethrow_exception(e);
}

void RecorderThread::run() {
  std::unique_ptr<Recorder> rec;
  std::uint64_t recGeneration = 0;
  std::unique_lock lock(m_);
  for (;;) {
    cv_.wait(lock, [&] { return quit_ || !jobs_.empty(); });
    if (jobs_.empty()) return;  // quit, with nothing left to write
    Job j = std::move(jobs_.front());
    jobs_.pop_front();
    queuedBytes_ -= j.frame.pixels.size();
    busy_ = true;
    lock.unlock();
    idle_.notify_all();  // room in the queue
    if (j.isOpen) {
      if (rec) {
        // As a recording's close always was: a failure is said (with where
        // the frames are kept) and the next recording opens all the same.
        try {
          rec->close();
        } catch (...) {
          logFailure(std::current_exception());
        }
        rec.reset();
      }
      recGeneration = j.generation;
      if (!j.open.empty()) {
        rec = std::make_unique<Recorder>(j.open);  // opens its files at the first frame
        spdlog::info("viewer: recording the frames that go into the pipeline to {}", j.open);
      }
    } else if (rec) {
      try {
        rec->writePlaced(j.frame, j.pose, j.timeS);
      } catch (...) {
        // The recording is abandoned (its journal keeps what it had), the
        // frames queued for it go with it, and the caller hears why.
        rec.reset();
        lock.lock();
        if (error_) logFailure(error_);  // the caller has not heard of an earlier failure yet: said here
        error_ = std::current_exception();
        errorGeneration_ = recGeneration;
        while (!jobs_.empty() && !jobs_.front().isOpen) {
          queuedBytes_ -= jobs_.front().frame.pixels.size();
          jobs_.pop_front();
        }
        lock.unlock();
      }
    }
    lock.lock();
    busy_ = false;
    if (jobs_.empty()) idle_.notify_all();
  }
}

std::optional<Mat4> Placer::place(const Frame& f) {
  auto pose = f.imageValid ? imageToReference(cfg, f) : std::nullopt;
  if (pose && !isFinite(*pose)) pose.reset();
  if (!pose && unplaced++ == 0)
    spdlog::warn("live frame {} cannot be placed (invalid status or no ImageToReference chain); such frames are "
                 "skipped and counted",
                 f.index);
  return pose;
}

Source recorded(Source src, const std::string& path) {
  if (path.empty()) return src;
  auto inner = src.run;
  src.run = [inner, path](const FrameSink& sink) {
    Recorder rec(path);
    inner([&](const Frame& f, const Mat4& pose, double t) {
      rec.write(f);
      sink(f, pose, t);
    });
  };
  return src;
}

}  // namespace pp5::host
