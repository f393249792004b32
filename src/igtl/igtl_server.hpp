#pragma once
// An OpenIGTLink server for any number of clients, on a thread of its own, so
// that no client ever slows its caller (issue 41's foundation). What it sends
// is what its caller publishes: each published message is kept as the newest
// of its type and device name, sent to every client at once (a slow client
// gets only the newest of each), to each newcomer when it connects, and as the
// answer to GET_<type> with that device name (or with none: every one of the
// type). It answers GET_CAPABIL with the types it sends, GET_STATUS with
// STATUS OK, and any other message with a STATUS error naming it.
//
// Bound to 127.0.0.1 unless another address is given (then the caller warns).
// Incoming messages are bounded in size, as the viewer's are.
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "core/grid.hpp"
#include "core/transform.hpp"

namespace pp5::igtl {

struct ServerOptions {
  std::string address = "127.0.0.1";
  int port = 18944;                          // 0: any free port (port() says which)
  std::size_t maxMessageBytes = 64 * 1024;   // the largest message a client may send
};

// "[ADDR:]PORT" (the form of run.igtl_serve) into the address and port;
// InputError naming `key` otherwise.
void parseServeAddress(const std::string& text, const std::string& key, std::string& address, int& port);

// A listening, non-blocking IPv4 TCP socket on address:port, with SO_REUSEADDR
// (so that a port in TIME_WAIT can be listened on again); the port it got
// into `boundPort`. InputError starting with `what` when it cannot.
int listenTcp(const std::string& address, int port, int backlog, int& boundPort, const std::string& what);

class Server {
public:
  // Binds and starts serving; InputError when the address cannot be bound.
  explicit Server(const ServerOptions& options);
  ~Server();  // closes every connection and joins the thread
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  int port() const;
  std::size_t clients() const;

  // A packed message (header and body, as igtl::MessageBase::Pack leaves it)
  // of `type` ("IMAGE", "TRANSFORM", ...) and `device`: the newest of its kind.
  void publish(const std::string& type, const std::string& device, std::string packed);
  // A uint8 IMAGE of `dims` (x fastest; z = 1 for a 2D image) whose voxel
  // (i, j, k) lies at pixelToFrame * (i, j, k, 1), its origin the voxels'
  // centre as OpenIGTLink defines it; InputError when it cannot be sent.
  void publishImage(const std::string& device, const Index3& dims, const std::uint8_t* voxels, const Mat4& pixelToFrame,
                    double timeS);

  struct Impl;

private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace pp5::igtl
