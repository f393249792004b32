#pragma once
// The transport: every byte the pipeline sends goes through here, and is
// counted here (per peer, both directions), never in the algorithms.
//
// Sends never block: a message is copied once into a buffer the transport
// owns and the send completes in the background. (The pipeline's messages
// flow host -> GP -> PP -> host; blocking sends of large messages around that
// cycle could deadlock.) Receives take whatever has arrived, from any rank,
// in per-sender order. Waiting polls and sleeps in short steps rather than
// spinning, because ranks share cores.
//
// A peer that vanishes must not hang the job: wait() gives up after the
// configured timeout with a CommError naming what it waited for.
#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

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

// How a loop with nothing to do waits, since ranks share cores: a few yields,
// then sleeps that double from 10 us up to kLongest (1 ms), so that an idle
// rank wakes about a thousand times a second, not five thousand (each wake
// is a context switch and an MPI probe, CPU taken from the ranks that work).
// A message that comes meanwhile waits half a millisecond on average.
class IdleBackoff {
public:
  static constexpr std::chrono::microseconds kLongest{1000};
  // After work: the next pause is short again.
  void reset() { idle_ = 0; }
  // How long the next pause() will be at most (zero: a yield).
  std::chrono::microseconds next() const;
  // What pause(cap) will do: sleep this long, or yield when it is zero.
  std::chrono::microseconds step(std::chrono::microseconds cap = kLongest) const;
  // Yields or sleeps the next step, at most `cap`, and lengthens the next.
  void pause(std::chrono::microseconds cap = kLongest);

private:
  static constexpr int kYields = 20, kSteps = kYields + 7;
  int idle_ = 0;
};

// The interface every rank loop talks through; the MPI implementation is
// behind comm/mpi.hpp (and is the only code that sees MPI), so the loops and
// their headers never include <mpi.h>. The counters live here, in the base,
// so every implementation counts the same way.
class Transport {
public:
  virtual ~Transport() = default;
  Transport(const Transport&) = delete;
  Transport& operator=(const Transport&) = delete;

  int rank() const { return rank_; }
  int size() const { return size_; }

  // Sends struct m (its Header's tag is the message tag) followed by `payload`.
  template <typename M>
  void send(int dest, const M& m, const void* payload = nullptr, std::size_t payloadBytes = 0) {
    static_assert(std::is_trivially_copyable_v<M>, "messages are plain structs");
    std::vector<std::byte> buf(sizeof(M) + payloadBytes);
    std::memcpy(buf.data(), &m, sizeof(M));
    if (payloadBytes) std::memcpy(buf.data() + sizeof(M), payload, payloadBytes);
    sendBuffer(dest, static_cast<int>(m.h.tag), std::move(buf));
  }
  // A message already assembled (struct first).
  virtual void sendBuffer(int dest, int tag, std::vector<std::byte>&& buf) = 0;

  // One message if one has arrived (also moves pending sends on).
  virtual std::optional<Message> poll() = 0;
  // The next message; CommError after the timeout, naming `waitingFor`.
  // The time spent here is counted as waiting.
  Message wait(const std::string& waitingFor);
  // Until every queued send has completed (CommError after the timeout).
  virtual void flush() = 0;

  // Every rank waits here until all have arrived (the ranks' "ready" before
  // the host starts acquiring).
  virtual void barrier() = 0;
  // Rank `root`'s struct m copied into every rank's m. A set-up collective,
  // not peer traffic: it is not counted per peer.
  template <typename M>
  void broadcast(M& m, int root) {
    static_assert(std::is_trivially_copyable_v<M>, "messages are plain structs");
    broadcastBytes(&m, sizeof m, root);
  }

  const std::vector<PeerCounters>& counters() const { return peers_; }
  PeerCounters totals() const;
  // Bytes sent, by what they are for (comm::trafficOf the tag).
  const std::array<std::uint64_t, kTrafficKinds>& bytesSentByKind() const { return byKind_; }
  double waitSeconds() const { return waitS_; }
  double timeoutS() const { return timeoutS_; }

protected:
  // timeoutS: the longest wait() for any message before it gives up.
  Transport(int rank, int size, double timeoutS);
  virtual void broadcastBytes(void* data, std::size_t bytes, int root) = 0;
  // What implementations call for each message, so counting is written once.
  void countSent(int dest, int tag, std::size_t bytes);
  void countReceived(int source, std::size_t bytes);

private:
  int rank_ = 0, size_ = 1;
  double timeoutS_;
  std::vector<PeerCounters> peers_;
  std::array<std::uint64_t, kTrafficKinds> byKind_{};
  double waitS_ = 0.0;
};

}  // namespace pp5::comm
