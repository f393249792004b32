#include "comm/local_transport.hpp"

#include <barrier>
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
  explicit Hub(int size) : inboxes(static_cast<std::size_t>(size)), sync(size) {}
  std::vector<Inbox> inboxes;
  std::barrier<> sync;
  std::vector<std::byte> broadcast;  // the root's bytes, between two barriers
};

namespace {

class LocalTransport final : public Transport {
public:
  LocalTransport(std::shared_ptr<LocalJob::Hub> hub, int rank, int size, double timeoutS)
      : Transport(rank, size, timeoutS), hub_(std::move(hub)) {}

  void sendBuffer(int dest, int tag, std::vector<std::byte>&& buf) override {
    if (dest < 0 || dest >= size())
      throw CommError(fmt::format("send to rank {}, but the job has {} ranks", dest, size()));
    countSent(dest, buf.size());
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
  void barrier() override { hub_->sync.arrive_and_wait(); }

protected:
  void broadcastBytes(void* data, std::size_t bytes, int root) override {
    if (rank() == root) hub_->broadcast.assign(static_cast<std::byte*>(data), static_cast<std::byte*>(data) + bytes);
    hub_->sync.arrive_and_wait();
    if (hub_->broadcast.size() != bytes)
      throw CommError(fmt::format("a broadcast of {} bytes received {}", bytes, hub_->broadcast.size()));
    if (rank() != root) std::memcpy(data, hub_->broadcast.data(), bytes);
    hub_->sync.arrive_and_wait();
  }

private:
  std::shared_ptr<LocalJob::Hub> hub_;
};

}  // namespace

LocalJob::LocalJob(int size, double timeoutS) : hub_(std::make_shared<Hub>(size)) {
  for (int r = 0; r < size; ++r) ranks_.push_back(std::make_unique<LocalTransport>(hub_, r, size, timeoutS));
}

LocalJob::~LocalJob() = default;

Transport& LocalJob::rank(int r) { return *ranks_.at(static_cast<std::size_t>(r)); }

}  // namespace pp5::comm
