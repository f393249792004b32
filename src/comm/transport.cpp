#include "comm/transport.hpp"

#include <climits>
#include <cstdio>
#include <cstdlib>
#include <thread>

#include <fmt/format.h>

namespace pp5::comm {

namespace {
// Queued send bytes above which send() waits for the oldest to complete, so
// a fast producer cannot queue without bound.
constexpr std::size_t kMaxPendingBytes = std::size_t{1} << 30;
}  // namespace

Transport::Transport(MPI_Comm comm, double timeoutS) : comm_(comm), timeoutS_(timeoutS) {
  MPI_Comm_rank(comm_, &rank_);
  MPI_Comm_size(comm_, &size_);
  peers_.resize(static_cast<std::size_t>(size_));
}

Transport::~Transport() {
  // Never leave MPI with a buffer it may still read.
  for (Pending& p : pending_) MPI_Wait(&p.request, MPI_STATUS_IGNORE);
}

void Transport::sendBuffer(int dest, int tag, std::vector<std::byte>&& buf) {
  if (dest < 0 || dest >= size_) throw CommError(fmt::format("send to rank {}, but the job has {} ranks", dest, size_));
  if (buf.size() > static_cast<std::size_t>(INT_MAX))
    throw CommError(fmt::format("a message of {} bytes (tag {}) is larger than MPI's int count", buf.size(), tag));
  PeerCounters& c = peers_[static_cast<std::size_t>(dest)];
  c.bytesSent += buf.size();
  ++c.messagesSent;
  pendingBytes_ += buf.size();
  pending_.push_back({MPI_REQUEST_NULL, std::move(buf)});
  Pending& p = pending_.back();
  MPI_Isend(p.buf.data(), static_cast<int>(p.buf.size()), MPI_BYTE, dest, tag, comm_, &p.request);
  progress();
  if (pendingBytes_ > kMaxPendingBytes) {
    const auto t0 = std::chrono::steady_clock::now();
    while (pendingBytes_ > kMaxPendingBytes / 2) {
      progress();
      if (std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() > timeoutS_)
        throw CommError(fmt::format("{} MiB of sends have not completed in {} s; a receiving rank may have died",
                                    pendingBytes_ >> 20, timeoutS_));
      std::this_thread::sleep_for(std::chrono::microseconds(50));
    }
  }
}

void Transport::progress() {
  // Completed sends leave in order; the oldest is usually the first done.
  while (!pending_.empty()) {
    int done = 0;
    MPI_Test(&pending_.front().request, &done, MPI_STATUS_IGNORE);
    if (!done) break;
    pendingBytes_ -= pending_.front().buf.size();
    pending_.pop_front();
  }
  // Later ones may be done while the oldest waits (a slow receiver); test a few.
  for (std::size_t i = 1; i < pending_.size() && i < 16; ++i) {
    int done = 0;
    if (pending_[i].request != MPI_REQUEST_NULL) MPI_Test(&pending_[i].request, &done, MPI_STATUS_IGNORE);
  }
}

std::optional<Message> Transport::poll() {
  progress();
  int flag = 0;
  MPI_Status st;
  MPI_Iprobe(MPI_ANY_SOURCE, MPI_ANY_TAG, comm_, &flag, &st);
  if (!flag) return std::nullopt;
  int count = 0;
  MPI_Get_count(&st, MPI_BYTE, &count);
  Message m;
  m.source = st.MPI_SOURCE;
  m.tag = st.MPI_TAG;
  m.bytes.resize(static_cast<std::size_t>(count));
  MPI_Recv(m.bytes.data(), count, MPI_BYTE, st.MPI_SOURCE, st.MPI_TAG, comm_, MPI_STATUS_IGNORE);
  PeerCounters& c = peers_[static_cast<std::size_t>(m.source)];
  c.bytesReceived += m.bytes.size();
  ++c.messagesReceived;
  return m;
}

Message Transport::wait(const std::string& waitingFor) {
  if (auto m = poll()) return std::move(*m);
  const auto t0 = std::chrono::steady_clock::now();
  // Ranks share cores: after a short burst of polls, sleep in growing steps
  // (up to 200 us, well under a 30 Hz frame) so a waiting rank leaves the
  // core to the ones that work.
  for (int idle = 0;; ++idle) {
    if (auto m = poll()) {
      waitS_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      return std::move(*m);
    }
    if (idle < 20) {
      std::this_thread::yield();
      continue;
    }
    const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (waited > timeoutS_)
      throw CommError(fmt::format("no message in {:.0f} s while waiting for {}; a rank may have died or hung "
                                  "(parallel.timeout_s)",
                                  timeoutS_, waitingFor));
    std::this_thread::sleep_for(std::chrono::microseconds(std::min(200, 10 * (idle - 19))));
  }
}

void Transport::flush() {
  const auto t0 = std::chrono::steady_clock::now();
  while (!pending_.empty()) {
    progress();
    if (pending_.empty()) break;
    if (std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() > timeoutS_)
      throw CommError(fmt::format("{} sends have not completed in {:.0f} s; a receiving rank may have died",
                                  pending_.size(), timeoutS_));
    std::this_thread::sleep_for(std::chrono::microseconds(50));
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

void abortJob(int rank, const char* role, const std::string& message) {
  std::fprintf(stderr, "pp5echo: rank %d (%s): %s\n", rank, role, message.c_str());
  std::fflush(stderr);
  MPI_Abort(MPI_COMM_WORLD, 1);
  std::_Exit(1);
}

bool launchedByMpi() {
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "SLURM_STEP_NUM_TASKS", "MPI_LOCALNRANKS"})
    if (std::getenv(v)) return true;
  return false;
}

}  // namespace pp5::comm
