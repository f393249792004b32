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

BackgroundRecorder::BackgroundRecorder(std::size_t maxQueuedBytes)
    : maxQueuedBytes_(maxQueuedBytes), thread_([this] { run(); }) {}

BackgroundRecorder::~BackgroundRecorder() {
  {
    const std::lock_guard lock(m_);
    queue_.push_back({Item::Stop, {}, {}, {}, 0});
    quit_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

void BackgroundRecorder::start(const std::string& path) {
  const std::lock_guard lock(m_);
  queue_.push_back({Item::Start, path, {}, {}, 0});
  cv_.notify_all();
}

void BackgroundRecorder::stop() {
  const std::lock_guard lock(m_);
  queue_.push_back({Item::Stop, {}, {}, {}, 0});
  cv_.notify_all();
}

void BackgroundRecorder::writePlaced(const Frame& f, const Mat4& imageToReference, double timeS) {
  std::unique_lock lock(m_);
  // The disk is behind: wait for it rather than lose a frame (one frame always fits).
  cv_.wait(lock, [&] { return queuedBytes_ == 0 || queuedBytes_ + f.pixels.size() <= maxQueuedBytes_; });
  queuedBytes_ += f.pixels.size();
  queue_.push_back({Item::Write, {}, f, imageToReference, timeS});
  cv_.notify_all();
}

void BackgroundRecorder::drain() {
  std::unique_lock lock(m_);
  cv_.wait(lock, [&] { return queue_.empty() && !busy_; });
}

std::string BackgroundRecorder::error() const {
  const std::lock_guard lock(m_);
  return error_;
}

void BackgroundRecorder::run() {
  std::unique_ptr<Recorder> rec;
  std::string path;
  std::unique_lock lock(m_);
  for (;;) {
    cv_.wait(lock, [&] { return !queue_.empty() || quit_; });
    if (queue_.empty()) break;
    Item item = std::move(queue_.front());
    queue_.pop_front();
    busy_ = true;
    lock.unlock();
    std::string failure;
    const auto failed = [&](const std::exception& e) {
      failure = fmt::format("recording {}: {}", path, e.what());
      spdlog::error("{}", failure);
    };
    if (item.kind != Item::Write && rec) {  // a start or a stop ends the open recording
      auto done = std::move(rec);
      try {
        done->close();
      } catch (const std::exception& e) {
        failed(e);
      }
    }
    if (item.kind == Item::Start) {
      rec = std::make_unique<Recorder>(item.path);  // opens nothing until its first frame
      path = item.path;
    }
    if (item.kind == Item::Write && rec) {
      try {
        rec->writePlaced(item.frame, item.pose, item.timeS);
      } catch (const std::exception& e) {
        failed(e);
        rec.reset();  // says where the frames written so far are kept; the rest wait for a new start
      }
    }
    lock.lock();
    if (item.kind == Item::Write) queuedBytes_ -= item.frame.pixels.size();
    if (!failure.empty()) error_ = failure;
    else if (item.kind == Item::Start) error_.clear();
    busy_ = false;
    cv_.notify_all();
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
