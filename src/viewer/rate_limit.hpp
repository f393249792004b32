#pragma once
// How often the viewer sends an image: at most `hz` a second on average, as a
// bucket of `burst` credits refilled at that rate. An image that comes a little
// early (the pipeline's ticks jitter) goes at once; with fixed slots instead, an
// image that once missed its slot would delay every later one by as much.
#include <algorithm>
#include <chrono>

namespace pp5::viewer {

class RateLimit {
public:
  using Clock = std::chrono::steady_clock;
  RateLimit(double hz, double burst, Clock::time_point now) : hz_(hz), burst_(burst), credit_(burst), at_(now) {}

  // How long until an image may go (zero: now).
  Clock::duration wait(Clock::time_point now) {
    refill(now);
    if (credit_ >= 1) return Clock::duration::zero();
    return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>((1.0 - credit_) / hz_)) +
           Clock::duration(1);
  }
  // Takes a credit if there is one.
  bool take(Clock::time_point now) {
    refill(now);
    if (credit_ < 1) return false;
    credit_ -= 1;
    return true;
  }
  // An image that goes whatever the credit (a new view's first): it spends
  // what there is. (Spending a credit it does not have, down to -1, keeps a
  // drag's views a little freer of the frames' images, 19 views/s against 17,
  // but delays the frames' images after each view: latency median 76 ms
  // against 64 in the browser test, docs/benchmarks.md.)
  void force(Clock::time_point now) {
    refill(now);
    credit_ = std::max(0.0, credit_ - 1);
  }
private:
  void refill(Clock::time_point now) {
    if (now > at_) credit_ = std::min(burst_, credit_ + std::chrono::duration<double>(now - at_).count() * hz_);
    at_ = std::max(at_, now);
  }
  double hz_, burst_, credit_;
  Clock::time_point at_;
};

}  // namespace pp5::viewer
