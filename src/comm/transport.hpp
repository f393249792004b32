#pragma once
// The MPI transport: every byte the pipeline sends goes through here, and is
// counted here (per peer, both directions), never in the algorithms.
//
// Sends never block: a message is copied once into a buffer the transport
// owns and sent with MPI_Isend; the buffer is freed when MPI is done with it.
// (The pipeline's messages flow host -> GP -> PP -> host; blocking sends of
// large messages around that cycle could deadlock.) Receives take whatever
// has arrived, from any rank, in MPI's per-sender order. Waiting polls and
// sleeps in short steps rather than spinning, because ranks share cores.
//
// A peer that vanishes must not hang the job: wait() gives up after the
// configured timeout with a CommError naming what it waited for.
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <deque>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include <mpi.h>

#include "comm/messages.hpp"

namespace pp5::comm {

class CommError : public std::runtime_error {
public:
  using std::runtime_error::runtime_error;
};

struct PeerCounters {
  std::uint64_t bytesSent = 0, messagesSent = 0, bytesReceived = 0, messagesReceived = 0;
};

struct Message {
  int source = -1;
  int tag = 0;
  std::vector<std::byte> bytes;

  const Header& header() const { return as<Header>(); }
  // The message's struct; CommError when the message is too short for it.
  template <typename M>
  const M& as() const {
    if (bytes.size() < sizeof(M))
      throw CommError("a message with tag " + std::to_string(tag) + " from rank " + std::to_string(source) +
                      " is " + std::to_string(bytes.size()) + " bytes, shorter than its header");
    return *reinterpret_cast<const M*>(bytes.data());
  }
  // The bytes after the struct M.
  template <typename M>
  std::span<const std::byte> payload() const {
    return std::span<const std::byte>(bytes).subspan(sizeof(M));
  }
};

class Transport {
public:
  // timeoutS: the longest wait() for any message before it gives up.
  Transport(MPI_Comm comm, double timeoutS);
  ~Transport();
  Transport(const Transport&) = delete;
  Transport& operator=(const Transport&) = delete;

  int rank() const { return rank_; }
  int size() const { return size_; }

  // Sends struct m (its Header's tag is the MPI tag) followed by `payload`.
  template <typename M>
  void send(int dest, const M& m, const void* payload = nullptr, std::size_t payloadBytes = 0) {
    std::vector<std::byte> buf(sizeof(M) + payloadBytes);
    std::memcpy(buf.data(), &m, sizeof(M));
    if (payloadBytes) std::memcpy(buf.data() + sizeof(M), payload, payloadBytes);
    sendBuffer(dest, static_cast<int>(m.h.tag), std::move(buf));
  }
  // A message already assembled (struct first).
  void sendBuffer(int dest, int tag, std::vector<std::byte>&& buf);

  // One message if one has arrived (also moves pending sends on).
  std::optional<Message> poll();
  // The next message; CommError after the timeout, naming `waitingFor`.
  // The time spent here is counted as waiting.
  Message wait(const std::string& waitingFor);
  // Until every queued send has completed (CommError after the timeout).
  void flush();

  const std::vector<PeerCounters>& counters() const { return peers_; }
  PeerCounters totals() const;
  double waitSeconds() const { return waitS_; }
  std::size_t pendingSends() const { return pending_.size(); }
  double timeoutS() const { return timeoutS_; }

private:
  struct Pending {
    MPI_Request request;
    std::vector<std::byte> buf;
  };
  MPI_Comm comm_;
  int rank_ = 0, size_ = 1;
  double timeoutS_;
  std::deque<Pending> pending_;
  std::size_t pendingBytes_ = 0;
  std::vector<PeerCounters> peers_;
  double waitS_ = 0.0;

  void progress();
};

// Prints "pp5echo: rank R (ROLE): message" on stderr and ends the whole job
// (MPI_Abort), so no rank is left waiting for this one.
[[noreturn]] void abortJob(int rank, const char* role, const std::string& message);

// True when this process was started by an MPI launcher (mpirun, mpiexec,
// srun), from its environment.
bool launchedByMpi();

}  // namespace pp5::comm
