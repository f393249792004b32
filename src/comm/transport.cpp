#include "comm/transport.hpp"

#include <algorithm>
#include <chrono>
#include <thread>

#include <fmt/format.h>

namespace pp5::comm {

Transport::Transport(int rank, int size, double timeoutS)
    : rank_(rank), size_(size), timeoutS_(timeoutS), peers_(static_cast<std::size_t>(size)) {}

void Transport::countSent(int dest, int tag, std::size_t bytes) {
  byKind_[static_cast<std::size_t>(trafficOf(tag))] += bytes;
  PeerCounters& c = peers_[static_cast<std::size_t>(dest)];
  c.bytesSent += bytes;
  ++c.messagesSent;
}

void Transport::countReceived(int source, std::size_t bytes) {
  PeerCounters& c = peers_[static_cast<std::size_t>(source)];
  c.bytesReceived += bytes;
  ++c.messagesReceived;
}

std::chrono::microseconds IdleBackoff::next() const {
  if (idle_ < kYields) return std::chrono::microseconds(0);
  const int doublings = std::min(idle_ - kYields, kSteps - kYields);  // 10 us << 7 = 1.28 ms: past kLongest
  return std::min(kLongest, std::chrono::microseconds(10 << doublings));
}

std::chrono::microseconds IdleBackoff::step(std::chrono::microseconds cap) const {
  return std::max(std::chrono::microseconds(0), std::min(next(), cap));
}

void IdleBackoff::pause(std::chrono::microseconds cap) {
  const std::chrono::microseconds step = this->step(cap);
  if (idle_ < kSteps) ++idle_;  // past the longest step: stays there
  if (step <= std::chrono::microseconds(0)) std::this_thread::yield();
  else std::this_thread::sleep_for(step);
}

Message Transport::wait(const std::string& waitingFor) {
  if (auto m = poll()) return std::move(*m);
  const auto t0 = std::chrono::steady_clock::now();
  IdleBackoff idle;
  for (;;) {
    if (auto m = poll()) {
      waitS_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      return std::move(*m);
    }
    const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (waited > timeoutS_)
      throw CommError(fmt::format("no message in {:.0f} s while waiting for {}; a rank may have died or hung "
                                  "(parallel.timeout_s)",
                                  timeoutS_, waitingFor));
    idle.pause();
  }
}

PeerCounters Transport::totals() const {
  PeerCounters t;
  for (const PeerCounters& c : peers_) {
    t.bytesSent += c.bytesSent;
    t.messagesSent += c.messagesSent;
    t.bytesReceived += c.bytesReceived;
    t.messagesReceived += c.messagesReceived;
  }
  return t;
}

}  // namespace pp5::comm
