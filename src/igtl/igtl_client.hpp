#pragma once
// OpenIGTLink live source: connects to a server (PLUS, a scanner, or
// pp5echo-igtl-server) and turns its IMAGE messages into Frames with their
// tracked poses.
//
// Pairing: PLUS sends each frame's TRANSFORMs first, then its IMAGE. The client
// keeps a short history of TRANSFORMs per device and gives every IMAGE, for
// each device, the one whose timestamp is nearest to the image's (within
// pairToleranceS). A TRANSFORM that arrives after its IMAGE is therefore only
// paired with later images; it never reaches back to one already delivered,
// because frames are handed on as soon as they arrive.
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "core/frame.hpp"

namespace pp5::igtl {

constexpr int kDefaultPort = 18944;  // IANA's port for OpenIGTLink

struct Endpoint {
  std::string host;
  int port = kDefaultPort;
};

// "igtl://host" or "igtl://host:port" (IPv6 hosts in brackets: igtl://[::1]:18944).
// Anything else is an InputError naming the URL.
Endpoint parseIgtlUrl(const std::string& url);
std::string toString(const Endpoint& e);  // "host:port"

struct ClientOptions {
  Endpoint endpoint;
  std::string imageDevice;          // empty: any IMAGE device
  double pairToleranceS = 0.02;     // a TRANSFORM pairs with an IMAGE whose timestamp is this close
  double connectTimeoutS = 5.0;     // the first connection
  bool reconnect = true;            // when the server goes away, try again ...
  double reconnectTimeoutS = 10.0;  // ... for this long, then end (what arrived is kept)
};

struct ClientStats {
  std::uint64_t images = 0;             // IMAGE messages turned into frames
  std::uint64_t transforms = 0;         // TRANSFORM messages received
  std::uint64_t paired = 0;             // transforms attached to frames
  std::uint64_t imagesWithoutPose = 0;  // frames with no paired TRANSFORM and no Image_<Frame> matrix
  std::uint64_t skipped = 0;            // other messages (STATUS, other devices, bad CRC), body skipped,
                                        // and the rejected images below
  std::uint64_t rejected = 0;           // IMAGEs a frame cannot hold (RGB, data shorter than the size): skipped
  std::uint64_t disconnects = 0;        // the server went away (or the stream broke)
  std::uint64_t reconnects = 0;         // ... and came back
  std::uint64_t bytes = 0;              // received, headers included
};

class Client {
public:
  explicit Client(ClientOptions opt);
  ~Client();
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;

  // Receives until `stop` becomes true (honoured within about 0.1 s), or the
  // server has been gone for longer than reconnectTimeoutS (at once when
  // reconnect is false). Each IMAGE becomes a Frame handed to onFrame in
  // arrival order: index counts frames from 0 across reconnections, timestamp is
  // the message's in seconds. Transforms: paired TRANSFORMs named after their
  // device (a trailing "Transform" dropped) in the order the devices were first
  // seen, then, for a device named "Image_<Frame>", "ImageTo<Frame>" = the
  // IMAGE's matrix times diag(spacing, 1), mapping pixel indices to mm.
  //
  // Throws DeviceError when the first connection cannot be made within
  // connectTimeoutS (naming host:port), and InputError when an IMAGE is of a
  // kind a Frame cannot hold (3D, more than one component, a scalar type other
  // than uint8 or uint16), naming the device. May be called again after it
  // returns. Sockets are plain POSIX with poll(), not igtl::ClientSocket: that
  // bounds the connect time and tells a quiet server from a closed one without
  // losing the bytes of a half-read message; OpenIGTLink does the messages.
  void run(const std::function<void(Frame&&)>& onFrame, const std::atomic<bool>& stop);

  // Safe to call from another thread while run() is going.
  ClientStats stats() const;
  // What run() does with a connection, on a stream that is already open (a
  // socketpair in tests and the fuzz target): decodes messages until the
  // stream ends or breaks, without connecting or reconnecting. Takes `fd`.
  void decode(int fd, const std::function<void(Frame&&)>& onFrame);

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace pp5::igtl
