#include "comm/local_transport.hpp"

#include <chrono>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <mutex>

#include <fmt/format.h>

namespace pp5::comm {

struct LocalJob::Hub {
  struct Inbox {
    std::mutex m;
    std::deque<Message> q;
  };
  Hub(int size, double timeoutS) : inboxes(static_cast<std::size_t>(size)), size(size), timeoutS(timeoutS) {}
  std::vector<Inbox> inboxes;
  std::vector<std::byte> broadcast;  // the root's bytes, between two barriers

  // A barrier that gives up after the timeout, and that abort() opens for
  // good, so that a rank that failed (a thread that threw) leaves none of the
  // others waiting for it: what MPI_Abort does for a job of processes.
  void arrive(int rank, const char* what) {
    std::unique_lock lock(m);
    if (aborted) throw CommError(fmt::format("rank {}: the job was aborted ({})", rank, what));
    const std::uint64_t gen = generation;
    if (++arrived == size) {
      arrived = 0;
      ++generation;
      cv.notify_all();
      return;
    }
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeoutS);
    if (!cv.wait_until(lock, deadline, [&] { return generation != gen || aborted; })) {
      --arrived;  // it leaves the barrier it gave up on
      throw CommError(fmt::format("rank {}: not every rank reached the {} in {:.0f} s; a rank may have died or hung "
                                  "(parallel.timeout_s)",
                                  rank, what, timeoutS));
    }
    if (aborted && generation == gen) throw CommError(fmt::format("rank {}: the job was aborted ({})", rank, what));
  }
  void abort() {
    const std::lock_guard lock(m);
    aborted = true;
    cv.notify_all();
  }

  std::mutex m;
  std::condition_variable cv;
  int size;
  double timeoutS;
  int arrived = 0;
  std::uint64_t generation = 0;
  bool aborted = false;
};

namespace {

class LocalTransport final : public Transport {
public:
  LocalTransport(std::shared_ptr<LocalJob::Hub> hub, int rank, int size, double timeoutS)
      : Transport(rank, size, timeoutS), hub_(std::move(hub)) {}

  void sendBuffer(int dest, int tag, std::vector<std::byte>&& buf) override {
    if (dest < 0 || dest >= size())
      throw CommError(fmt::format("send to rank {}, but the job has {} ranks", dest, size()));
    countSent(dest, tag, buf.size());
    Message m;
    m.source = rank();
    m.tag = tag;
    m.bytes = std::move(buf);
    auto& in = hub_->inboxes[static_cast<std::size_t>(dest)];
    const std::lock_guard lock(in.m);
    in.q.push_back(std::move(m));
  }

  std::optional<Message> poll() override {
    auto& in = hub_->inboxes[static_cast<std::size_t>(rank())];
    std::optional<Message> m;
    {
      const std::lock_guard lock(in.m);
      if (in.q.empty()) return std::nullopt;
      m = std::move(in.q.front());
      in.q.pop_front();
    }
    countReceived(m->source, m->bytes.size());
    return m;
  }

  void flush() override {}  // a send is delivered when it returns
  void barrier() override { hub_->arrive(rank(), "barrier"); }

protected:
  void broadcastBytes(void* data, std::size_t bytes, int root) override {
    if (rank() == root) hub_->broadcast.assign(static_cast<std::byte*>(data), static_cast<std::byte*>(data) + bytes);
    hub_->arrive(rank(), "broadcast");
    const bool same = hub_->broadcast.size() == bytes;
    if (same && rank() != root) std::memcpy(data, hub_->broadcast.data(), bytes);
    hub_->arrive(rank(), "broadcast");  // every rank has read before the next broadcast writes
    if (!same) throw CommError(fmt::format("a broadcast of {} bytes received {}", bytes, hub_->broadcast.size()));
  }

private:
  std::shared_ptr<LocalJob::Hub> hub_;
};

}  // namespace

LocalJob::LocalJob(int size, double timeoutS) : hub_(std::make_shared<Hub>(size, timeoutS)) {
  for (int r = 0; r < size; ++r) ranks_.push_back(std::make_unique<LocalTransport>(hub_, r, size, timeoutS));
}

LocalJob::~LocalJob() = default;

Transport& LocalJob::rank(int r) { return *ranks_.at(static_cast<std::size_t>(r)); }

void LocalJob::abort() { hub_->abort(); }

}  // namespace pp5::comm
