#include "host/acquisition.hpp"

#include <algorithm>
#include <cstdio>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "core/error.hpp"

namespace pp5::host {

namespace {
struct StopRequested {};
}  // namespace

Mat4 preprocessPixels(const Preprocess& p) {
  Mat4 m(1.0);
  if (p.crop.z > 0) {
    Mat4 t(1.0);
    t[3] = Vec4(p.crop.x, p.crop.y, 0.0, 1.0);
    m = m * t;
  }
  if (p.subsample > 1) {
    const int s = p.subsample;
    Mat4 t(1.0);
    t[0][0] = s;
    t[1][1] = s;
    t[3] = Vec4(0.5 * (s - 1), 0.5 * (s - 1), 0.0, 1.0);
    m = m * t;
  }
  return m;
}

void preprocess(const Preprocess& p, Frame& f, Mat4& pose) {
  if (p.identity()) return;
  const int bpp = bytesPerPixel(f.pixelType);
  if (p.crop.z > 0) {
    const int x = p.crop.x, y = p.crop.y, w = p.crop.z, h = p.crop.w;
    if (x < 0 || y < 0 || w <= 0 || h <= 0 || x + w > f.width || y + h > f.height)
      throw InputError(fmt::format("frame {}: run.crop = [{}, {}, {}, {}] does not fit inside the {}x{} image", f.index,
                                   x, y, w, h, f.width, f.height));
    std::vector<std::uint8_t> px(static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * bpp);
    for (int r = 0; r < h; ++r)
      std::copy_n(f.pixels.data() + (static_cast<std::size_t>(y + r) * f.width + x) * bpp, static_cast<std::size_t>(w) * bpp,
                  px.data() + static_cast<std::size_t>(r) * w * bpp);
    f.pixels = std::move(px);
    f.width = w;
    f.height = h;
  }
  if (p.subsample > 1) {
    const int s = p.subsample, w = f.width / s, h = f.height / s;
    if (w < 1 || h < 1)
      throw InputError(fmt::format("frame {}: run.subsample = {} leaves nothing of the {}x{} image", f.index, s, f.width,
                                   f.height));
    Frame out;
    out.allocate(w, h, f.pixelType);
    for (int r = 0; r < h; ++r)
      for (int c = 0; c < w; ++c) {
        double sum = 0.0;
        for (int dy = 0; dy < s; ++dy)
          for (int dx = 0; dx < s; ++dx) sum += f.value(c * s + dx, r * s + dy);
        const double v = std::round(sum / (s * s));
        const std::size_t i = static_cast<std::size_t>(r) * w + c;
        if (f.pixelType == PixelType::U8) {
          out.pixels[i] = static_cast<std::uint8_t>(v);
        } else {
          const auto u = static_cast<std::uint16_t>(v);
          out.pixels[2 * i] = static_cast<std::uint8_t>(u & 0xff);
          out.pixels[2 * i + 1] = static_cast<std::uint8_t>(u >> 8);
        }
      }
    f.pixels = std::move(out.pixels);
    f.width = w;
    f.height = h;
  }
  pose = pose * preprocessPixels(p);
}

DropPolicy dropPolicyFromName(const std::string& name) { return enumFromName<DropPolicy>(name); }

Acquisition::Acquisition(Source source, Preprocess pre, std::size_t capacity, DropPolicy policy, double paceFps,
                         double captureIntervalMm)
    : source_(std::move(source)), pre_(pre), capacity_(std::max<std::size_t>(1, capacity)), policy_(policy),
      paceFps_(paceFps), live_(source_.live || paceFps > 0.0), capture_(captureIntervalMm) {
  thread_ = std::thread([this] {
    try {
      const auto t0 = std::chrono::steady_clock::now();
      std::uint64_t n = 0;
      source_.run([&](const Frame& f, const Mat4& pose, double t) {
        if (stop_) throw StopRequested{};
        if (paceFps_ > 0.0) {
          // The frame's time in the paced timeline; a stop ends the wait at once.
          const auto due = t0 + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                    std::chrono::duration<double>(static_cast<double>(n) / paceFps_));
          std::unique_lock<std::mutex> lock(m_);
          if (cv_.wait_until(lock, due, [this] { return stop_.load(); })) throw StopRequested{};
        }
        ++n;
        ++given_;
        AcquiredFrame a{f, pose, t, {}};
        preprocess(pre_, a.frame, a.imageToReference);
        if (!capture_.take(a.frame, a.imageToReference)) {
          ++skipped_;
          return;
        }
        a.arrival = std::chrono::steady_clock::now();
        push(std::move(a));
      });
    } catch (const StopRequested&) {
    } catch (...) {
      const std::lock_guard<std::mutex> lock(m_);
      error_ = std::current_exception();
    }
    const std::lock_guard<std::mutex> lock(m_);
    done_ = true;
    cv_.notify_all();
  });
}

Acquisition::~Acquisition() {
  stop();
  if (thread_.joinable()) thread_.join();
}

void Acquisition::stop() {
  bool first = false;
  {
    // Under the lock, so that a thread between its check of stop_ and its wait cannot miss the wake-up.
    const std::lock_guard<std::mutex> lock(m_);
    first = !stop_.exchange(true);
  }
  if (first && source_.interrupt) source_.interrupt();
  cv_.notify_all();
}

void Acquisition::push(AcquiredFrame&& f) {
  std::unique_lock<std::mutex> lock(m_);
  if (q_.size() >= capacity_) {
    if (!live_) {
      cv_.wait(lock, [&] { return q_.size() < capacity_ || stop_; });
      if (stop_) throw StopRequested{};
    } else if (policy_ == DropPolicy::Oldest) {
      q_.pop_front();
      ++dropped_;
    } else {
      ++dropped_;
      return;
    }
  }
  q_.push_back(std::move(f));
  ++delivered_;
  cv_.notify_all();  // a consumer in popFor
}

bool Acquisition::whilePaused() {
  AcquiredFrame unused;
  if (live_ && tryPop(unused)) {
    ++passedWhilePaused_;
    return true;
  }
  if (finished()) return false;
  std::this_thread::sleep_for(std::chrono::milliseconds(2));
  return true;
}

void Acquisition::logProgress(std::uint64_t through, double seconds) const {
  const std::uint64_t at = std::max<std::uint64_t>(1, given_);
  const double fps = static_cast<double>(through) / seconds;
  if (source_.frames)
    spdlog::info("run: frame {}/{}, {:.1f} frames/s, {:.0f} s left", at, source_.frames, fps,
                 static_cast<double>(source_.frames - std::min(at, source_.frames)) * seconds /
                     static_cast<double>(at));
  else
    spdlog::info("run: frame {}, {:.1f} frames/s", at, fps);
}

void Acquisition::printCounts() const {
  if (dropped_)
    std::printf("  dropped %llu frames (the source ahead of the pipeline; run.pace_fps = %g, run.queue_frames = %zu, "
                "run.drop = %s)\n",
                static_cast<unsigned long long>(dropped_.load()), paceFps_, capacity_, enumName(policy_).data());
  if (passedWhilePaused_)
    std::printf("  %llu frames went by while the viewer paused acquisition\n",
                static_cast<unsigned long long>(passedWhilePaused_));
  if (skipped_)
    std::printf("  constant-interval capture (every %g mm) left out %llu frames\n", capture_.intervalMm(),
                static_cast<unsigned long long>(skipped_.load()));
}

bool Acquisition::popFor(AcquiredFrame& out, std::chrono::milliseconds timeout) {
  std::unique_lock<std::mutex> lock(m_);
  cv_.wait_for(lock, timeout, [this] { return !q_.empty() || done_; });
  if (q_.empty()) return false;
  out = std::move(q_.front());
  q_.pop_front();
  cv_.notify_all();
  return true;
}

bool Acquisition::tryPop(AcquiredFrame& out) {
  const std::lock_guard<std::mutex> lock(m_);
  if (q_.empty()) return false;
  out = std::move(q_.front());
  q_.pop_front();
  cv_.notify_all();
  return true;
}

bool Acquisition::finished() {
  const std::lock_guard<std::mutex> lock(m_);
  if (error_) std::rethrow_exception(error_);
  return done_ && q_.empty();
}

}  // namespace pp5::host
