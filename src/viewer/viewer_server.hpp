#pragma once
// The live viewer's server (issue 16's foundation): HTTP for the page's own
// static files and a WebSocket per browser, on a thread of its own so that it
// never slows the pipeline. Boost.Beast (Debian's libboost-dev).
//
// - Each client gets the newest message of each kind only: a slow client
//   skips images, and nothing queues without bound.
// - Replies to a client's control messages are never skipped.
// - Security: bound to loopback by default; any other address needs a token,
//   which every request must carry (?token=...). Without a token, a request
//   must name this machine in its Host header (the bound address, 127.0.0.1,
//   localhost or [::1]): a page served from a name that rebinds to 127.0.0.1
//   names its own. A request whose Origin is not the page's own is refused.
//   Static files come only from the viewer's own folder (no path traversal).
//   Incoming messages are bounded in size, and in rate per client, so that
//   one client cannot silence another.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

namespace pp5::viewer {

// Whether `address` is a loopback address (127.0.0.0/8, ::1).
bool isLoopback(const std::string& address);

// Whether a request's Host header names this machine as a page of a server
// bound to `boundAddress` would: that address, 127.0.0.1, localhost or [::1],
// with any port (an ssh tunnel changes it) or none.
bool isOwnHost(const std::string& hostHeader, const std::string& boundAddress);

struct ServerOptions {
  std::string address = "127.0.0.1";
  int port = 0;              // 0: any free port (port() says which)
  std::string root;          // the folder whose files are served
  std::string token;         // required for a non-loopback address
  std::size_t maxMessageBytes = 64 * 1024;  // largest message a client may send
  int maxMessagesPerSecond = 240;  // each client's; more are answered with an error
};

class Server {
public:
  // Binds and starts serving. InputError for a non-loopback address without a
  // token, a missing root folder, or an address or port that cannot be bound.
  explicit Server(const ServerOptions& options);
  ~Server();  // closes every connection and joins the thread
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  int port() const;
  // The page's address, with the token when there is one.
  std::string url() const;
  std::size_t clients() const;

  // Sends `bytes` to every client as a binary message; a client still busy
  // with an earlier message of the same `channel` gets only the newest one.
  void publish(int channel, std::string bytes);
  // A client's text message: `handler` answers "" (accepted) or an error,
  // which goes back to that client as {"error": "..."}. It runs on the
  // server's thread, so it must be quick.
  void onMessage(std::function<std::string(const std::string&)> handler);

  struct Impl;

private:
  std::shared_ptr<Impl> impl_;
};

}  // namespace pp5::viewer
