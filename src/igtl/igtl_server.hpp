#pragma once
// An OpenIGTLink server for any number of clients, on a thread of its own, so
// that no client ever slows its caller (issue 41). What it sends is what its
// caller publishes:
//  - messages (frames, transforms, rendered views): each kept as the newest of
//    its type and device name, sent to every client as soon as it can take
//    it (a slow client gets only the newest of each), to each newcomer when
//    it connects, and as the answer to GET_<type>;
//  - the live volume: whole to a newcomer and on GET_IMAGE, then as
//    sub-volume IMAGEs of the bricks that changed since that client last got
//    them (so an update a client has not taken merges into the next);
//  - command replies, to the client that asked.
// It answers GET_CAPABIL with the types it sends, GET_STATUS with STATUS OK,
// PlusServer's commands (STRING CMD_<uid>) through the caller's handler, and
// any other message with a STATUS error naming it. A client that sends what
// MessageReader refuses (igtl/igtl_protocol.hpp) is logged in one line and
// dropped; the others go on.
//
// Bound to 127.0.0.1 unless another address is given (then the caller warns).
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "core/grid.hpp"
#include "core/transform.hpp"
#include "igtl/igtl_protocol.hpp"

namespace pp5::igtl {

struct ServerOptions {
  std::string address = "127.0.0.1";
  int port = 18944;                          // 0: any free port (port() says which)
  std::size_t maxMessageBytes = 64 * 1024;   // the largest message body a client may send
  int commandsPerSecond = 20;                // each client's budget; beyond it a command is refused
};

// The live volume's sub-volume updates are in bricks of this many voxels a side.
constexpr int kVolumeBrick = 16;

// Answers a command: ok and the reply's message. May be called from any
// thread, once; a reply to a client that has gone is dropped.
using CommandReply = std::function<void(bool ok, const std::string& message)>;
// Called on the server's thread for each command; must return soon (long
// work goes to the caller's thread, which replies when it is done).
using CommandHandler = std::function<void(const Command& command, CommandReply reply)>;

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
  // The commands' handler (none: every command is answered FAIL). Once it
  // returns, the handler it replaced is not running and will not be called.
  void onCommand(CommandHandler handler);

  // A packed message (header and body, as igtl::MessageBase::Pack leaves it)
  // of `type` ("IMAGE", "TRANSFORM", ...) and `device`: the newest of its kind.
  void publish(const std::string& type, const std::string& device, std::string packed);
  // A message of `type` and `device` that `pack` packs on the server's thread
  // when its turn comes (a newer one published first replaces it unpacked),
  // so that the publisher does not pay for the packing. An InputError from
  // `pack` is logged once for that kind, and the message is not sent.
  void publishLater(const std::string& type, const std::string& device, std::function<std::string()> pack);
  // A uint8 IMAGE of `dims` (x fastest; z = 1 for a 2D image) whose voxel
  // (i, j, k) lies at pixelToFrame * (i, j, k, 1), its origin the voxels'
  // centre as OpenIGTLink defines it; `components` bytes a voxel (3: RGB).
  // The pixels are copied and packed as publishLater packs.
  void publishImage(const std::string& device, const Index3& dims, const std::uint8_t* voxels, const Mat4& pixelToFrame,
                    double timeS, int components = 1);
  // The live volume (uint8, x fastest) of `dims` at `pixelToFrame` (as
  // publishImage). `changed` has one byte per brick of kVolumeBrick voxels
  // (x fastest; nonzero: changed since the last call); empty means every
  // brick. A new device name, size or geometry sends the whole volume again.
  void publishVolume(const std::string& device, const Index3& dims, std::shared_ptr<const std::vector<std::uint8_t>> voxels,
                     const Mat4& pixelToFrame, const std::vector<std::uint8_t>& changed, double timeS);
  // The bricks of `dims` along each axis.
  static Index3 bricks(const Index3& dims);

  struct Impl;

private:
  std::shared_ptr<Impl> impl_;  // shared with the command replies still out
};

}  // namespace pp5::igtl
