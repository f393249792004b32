#include "comm/mpi.hpp"

#include <climits>
#include <cstdio>
#include <cstdlib>
#include <chrono>
#include <deque>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <mpi.h>

namespace pp5::comm {

namespace {

// Queued send bytes above which send() waits for the oldest to complete, so
// a fast producer cannot queue without bound.
constexpr std::size_t kMaxPendingBytes = std::size_t{1} << 30;

// Sends with MPI_Isend from a buffer the transport owns, freed when MPI is
// done with it; receives whatever has arrived (MPI_Iprobe), from any rank.
class MpiTransport final : public Transport {
public:
  MpiTransport(MPI_Comm comm, int rank, int size, double timeoutS) : Transport(rank, size, timeoutS), comm_(comm) {}
  ~MpiTransport() override {
    // Never leave MPI with a buffer it may still read.
    for (Pending& p : pending_) MPI_Wait(&p.request, MPI_STATUS_IGNORE);
  }

  void sendBuffer(int dest, int tag, std::vector<std::byte>&& buf) override {
    if (dest < 0 || dest >= size())
      throw CommError(fmt::format("send to rank {}, but the job has {} ranks", dest, size()));
    if (buf.size() > static_cast<std::size_t>(INT_MAX))
      throw CommError(fmt::format("a message of {} bytes (tag {}) is larger than MPI's int count", buf.size(), tag));
    countSent(dest, tag, buf.size());
    pendingBytes_ += buf.size();
    pending_.push_back({MPI_REQUEST_NULL, std::move(buf)});
    Pending& p = pending_.back();
    MPI_Isend(p.buf.data(), static_cast<int>(p.buf.size()), MPI_BYTE, dest, tag, comm_, &p.request);
    progress();
    if (pendingBytes_ > kMaxPendingBytes) {
      const auto t0 = std::chrono::steady_clock::now();
      while (pendingBytes_ > kMaxPendingBytes / 2) {
        progress();
        if (std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() > timeoutS())
          throw CommError(fmt::format("{} MiB of sends have not completed in {} s; a receiving rank may have died",
                                      pendingBytes_ >> 20, timeoutS()));
        std::this_thread::sleep_for(std::chrono::microseconds(50));
      }
    }
  }

  std::optional<Message> poll() override {
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
    countReceived(m.source, m.bytes.size());
    return m;
  }

  void flush() override {
    const auto t0 = std::chrono::steady_clock::now();
    while (!pending_.empty()) {
      progress();
      if (pending_.empty()) break;
      if (std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() > timeoutS())
        throw CommError(fmt::format("{} sends have not completed in {:.0f} s; a receiving rank may have died",
                                    pending_.size(), timeoutS()));
      std::this_thread::sleep_for(std::chrono::microseconds(50));
    }
  }

  void barrier() override { MPI_Barrier(comm_); }

protected:
  void broadcastBytes(void* data, std::size_t bytes, int root) override {
    if (bytes > static_cast<std::size_t>(INT_MAX))
      throw CommError(fmt::format("a broadcast of {} bytes is larger than MPI's int count", bytes));
    MPI_Bcast(data, static_cast<int>(bytes), MPI_BYTE, root, comm_);
  }

private:
  struct Pending {
    MPI_Request request;
    std::vector<std::byte> buf;
  };
  MPI_Comm comm_;
  std::deque<Pending> pending_;
  std::size_t pendingBytes_ = 0;

  void progress() {
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
};

}  // namespace

MpiSession::MpiSession() {
  int provided = 0;
  MPI_Init_thread(nullptr, nullptr, MPI_THREAD_FUNNELED, &provided);
  MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &size_);
}

MpiSession::~MpiSession() { MPI_Finalize(); }

std::unique_ptr<Transport> MpiSession::transport(double timeoutS) const {
  return std::make_unique<MpiTransport>(MPI_COMM_WORLD, rank_, size_, timeoutS);
}

double MpiSession::pingPongSeconds(std::size_t bytes, int reps, int blocks) const {
  if (size_ < 2 || rank_ > 1) throw CommError("a ping-pong runs between ranks 0 and 1 of a job of two or more");
  if (bytes > static_cast<std::size_t>(INT_MAX))
    throw CommError(fmt::format("a ping-pong message of {} bytes is larger than MPI's int count", bytes));
  std::vector<char> buf(bytes, 1);
  const int n = static_cast<int>(bytes);
  double best = 1e300;
  for (int b = 0; b < blocks; ++b) {
    MPI_Barrier(MPI_COMM_WORLD);
    const double t0 = MPI_Wtime();
    for (int i = 0; i < reps; ++i) {
      if (rank_ == 0) {
        MPI_Send(buf.data(), n, MPI_BYTE, 1, 0, MPI_COMM_WORLD);
        MPI_Recv(buf.data(), n, MPI_BYTE, 1, 0, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
      } else {
        MPI_Recv(buf.data(), n, MPI_BYTE, 0, 0, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
        MPI_Send(buf.data(), n, MPI_BYTE, 0, 0, MPI_COMM_WORLD);
      }
    }
    best = std::min(best, (MPI_Wtime() - t0) / (2.0 * reps));
  }
  return best;
}

void abortJob(int rank, const char* role, const std::string& message) {
  std::fprintf(stderr, "pp5echo: rank %d (%s): %s\n", rank, role, message.c_str());
  std::fflush(stderr);
  abortJobQuietly();
}

void abortJobQuietly() {
  MPI_Abort(MPI_COMM_WORLD, 1);
  std::_Exit(1);
}

bool launchedByMpi() {
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "SLURM_STEP_NUM_TASKS", "MPI_LOCALNRANKS"})
    if (std::getenv(v)) return true;
  return false;
}

}  // namespace pp5::comm
