#pragma once
// A WebSocket client for the viewer's tests (Boost.Beast, blocking), on 127.0.0.1.
#include <string>

// Boost 1.74's asio uses std::exchange without including <utility> (C++20, GCC 12).
#include <utility>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <sys/socket.h>
#include <sys/time.h>

namespace pp5::test {

struct Client {
  boost::asio::io_context ioc;
  boost::beast::websocket::stream<boost::asio::ip::tcp::socket> ws{ioc};
  // Connects to 127.0.0.1 and upgrades; `origin` empty: none sent (not a
  // browser). `host`: the Host header's name (a rebinding page sends its own).
  void connect(int port, const std::string& origin, const std::string& target = "/ws",
               const std::string& host = "127.0.0.1") {
    namespace websocket = boost::beast::websocket;
    boost::asio::ip::tcp::resolver resolver(ioc);
    boost::asio::connect(ws.next_layer(), resolver.resolve("127.0.0.1", std::to_string(port)));
    ws.set_option(websocket::stream_base::decorator([origin](websocket::request_type& r) {
      if (!origin.empty()) r.set(boost::beast::http::field::origin, origin);
    }));
    ws.handshake(host + ":" + std::to_string(port), target);
    // A read that waits too long fails instead of hanging the test.
    timeval tv{10, 0};
    ::setsockopt(ws.next_layer().native_handle(), SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  }
  std::string read() {
    boost::beast::flat_buffer b;
    ws.read(b);
    return boost::beast::buffers_to_string(b.data());
  }
};

}  // namespace pp5::test
