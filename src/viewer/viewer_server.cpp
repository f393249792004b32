#include "viewer/viewer_server.hpp"

#include <algorithm>
#include <atomic>
#include <deque>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>
#include <vector>

// Boost 1.74's asio uses std::exchange without including <utility> (C++20, GCC 12).
#include <utility>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::viewer {

namespace fs = std::filesystem;
namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;

namespace {

std::string contentType(const fs::path& p) {
  static const std::map<std::string, std::string> types = {
      {".html", "text/html; charset=utf-8"}, {".js", "text/javascript; charset=utf-8"},
      {".css", "text/css; charset=utf-8"},   {".json", "application/json"},
      {".png", "image/png"},                 {".jpg", "image/jpeg"},
      {".svg", "image/svg+xml"},             {".ico", "image/x-icon"}};
  const auto it = types.find(p.extension().string());
  return it == types.end() ? "application/octet-stream" : it->second;
}

// The query parameter `key` of a request target, "" when absent.
std::string queryValue(std::string_view target, std::string_view key) {
  const auto q = target.find('?');
  if (q == std::string_view::npos) return {};
  std::string_view rest = target.substr(q + 1);
  while (!rest.empty()) {
    const auto amp = rest.find('&');
    const std::string_view kv = rest.substr(0, amp);
    const auto eq = kv.find('=');
    if (kv.substr(0, eq) == key) return eq == std::string_view::npos ? std::string() : std::string(kv.substr(eq + 1));
    if (amp == std::string_view::npos) break;
    rest = rest.substr(amp + 1);
  }
  return {};
}

}  // namespace

bool isLoopback(const std::string& address) {
  boost::system::error_code ec;
  const auto a = net::ip::make_address(address, ec);
  return !ec && a.is_loopback();
}

bool isOwnHost(const std::string& hostHeader, const std::string& boundAddress) {
  std::string name = hostHeader;
  if (!name.empty() && name.front() == '[') {  // [v6]:port
    const auto close = name.find(']');
    if (close == std::string::npos) return false;
    const std::string rest = name.substr(close + 1);
    if (!rest.empty() && rest.front() != ':') return false;
    name = name.substr(1, close - 1);
  } else if (const auto colon = name.find(':'); colon != std::string::npos) {
    name = name.substr(0, colon);
  }
  if (name.empty()) return false;
  std::string lower;
  for (const char c : name) lower += static_cast<char>(c >= 'A' && c <= 'Z' ? c - 'A' + 'a' : c);
  return lower == "localhost" || lower == "127.0.0.1" || lower == "::1" || lower == boundAddress;
}

// The handlers hold a plain pointer to the Impl: it outlives the io thread
// (~Server joins it first), and the io_context, declared after everything the
// sessions touch, destroys the handlers (and with them the sessions) first.
struct Server::Impl {
  ServerOptions options;
  fs::path root;
  std::atomic<std::size_t> clientCount{0};
  std::mutex handlerMutex;
  std::function<std::string(const std::string&)> handler;

  class WsSession;
  std::vector<std::weak_ptr<WsSession>> sessions;  // touched on the io thread only

  net::io_context ioc{1};
  tcp::acceptor acceptor{ioc};
  std::thread thread;

  // One browser's WebSocket: the newest message per channel, replies in order.
  class WsSession : public std::enable_shared_from_this<WsSession> {
  public:
    WsSession(Impl& server, tcp::socket&& socket) : server_(server), ws_(std::move(socket)) {}

    void start(http::request<http::string_body> req) {
      ws_.read_message_max(server_.options.maxMessageBytes);
      ws_.async_accept(req, [self = shared_from_this()](beast::error_code ec) {
        if (ec) return;
        ++self->server_.clientCount;
        self->accepted_ = true;
        self->server_.sessions.push_back(self);
        self->read();
      });
    }
    ~WsSession() {
      if (accepted_) --server_.clientCount;
    }

    void publish(int channel, std::shared_ptr<const std::string> msg) {
      latest_[channel] = std::move(msg);
      write();
    }
    void close() {
      beast::error_code ec;
      beast::get_lowest_layer(ws_).socket().close(ec);
    }

  private:
    Impl& server_;
    websocket::stream<beast::tcp_stream> ws_;
    beast::flat_buffer in_;
    bool accepted_ = false, writing_ = false;
    std::map<int, std::shared_ptr<const std::string>> latest_;  // newest unsent message per channel
    std::deque<std::string> replies_;
    std::shared_ptr<const std::string> current_;
    std::deque<std::chrono::steady_clock::time_point> recent_;  // this client's messages in the last second

    // Whether this client may send one more message now (its own budget).
    bool withinRate() {
      const auto now = std::chrono::steady_clock::now();
      while (!recent_.empty() && now - recent_.front() > std::chrono::seconds(1)) recent_.pop_front();
      if (recent_.size() >= static_cast<std::size_t>(server_.options.maxMessagesPerSecond)) return false;
      recent_.push_back(now);
      return true;
    }

    void read() {
      ws_.async_read(in_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
        if (ec) return;  // closed, too large or broken: the session ends
        const std::string text = beast::buffers_to_string(self->in_.data());
        self->in_.consume(self->in_.size());
        std::string error;
        if (!self->withinRate()) {
          error = fmt::format("too many control messages: at most {} a second", self->server_.options.maxMessagesPerSecond);
        } else {
          const std::lock_guard lock(self->server_.handlerMutex);
          error = self->server_.handler ? self->server_.handler(text) : std::string("no control is accepted");
        }
        if (!error.empty()) {
          std::string quoted;
          for (const char c : error) quoted += c == '"' || c == '\\' ? std::string("\\") + c : std::string(1, c);
          self->replies_.push_back("{\"error\": \"" + quoted + "\"}");
          self->write();
        }
        self->read();
      });
    }

    void write() {
      if (writing_ || !accepted_) return;
      bool text = false;
      if (!replies_.empty()) {
        current_ = std::make_shared<const std::string>(std::move(replies_.front()));
        replies_.pop_front();
        text = true;
      } else {
        const auto it = std::find_if(latest_.begin(), latest_.end(), [](const auto& kv) { return kv.second != nullptr; });
        if (it == latest_.end()) return;
        current_ = std::move(it->second);
        it->second.reset();
      }
      writing_ = true;
      ws_.binary(!text);
      ws_.async_write(net::buffer(*current_), [self = shared_from_this()](beast::error_code ec, std::size_t) {
        self->writing_ = false;
        self->current_.reset();
        if (ec) return;
        self->write();
      });
    }
  };

  // One HTTP connection: static files, or the upgrade to a WebSocket.
  class HttpSession : public std::enable_shared_from_this<HttpSession> {
  public:
    HttpSession(Impl& server, tcp::socket&& socket) : server_(server), stream_(std::move(socket)) {}
    void start() { read(); }

  private:
    Impl& server_;
    beast::tcp_stream stream_;
    beast::flat_buffer buffer_;
    http::request<http::string_body> req_;

    void read() {
      req_ = {};
      stream_.expires_after(std::chrono::seconds(30));
      http::async_read(stream_, buffer_, req_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
        if (ec) return;
        self->handle();
      });
    }

    void reply(http::status status, std::string body, const std::string& type) {
      auto res = std::make_shared<http::response<http::string_body>>(status, req_.version());
      res->set(http::field::server, "pp5echo");
      res->set(http::field::content_type, type);
      res->set(http::field::cache_control, "no-store");
      res->keep_alive(req_.keep_alive());
      res->body() = std::move(body);
      res->prepare_payload();
      http::async_write(stream_, *res, [self = shared_from_this(), res](beast::error_code ec, std::size_t) {
        if (ec || !res->keep_alive()) {
          beast::error_code ignored;
          self->stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
          return;
        }
        self->read();
      });
    }

    void handle() {
      const std::string target(req_.target());
      if (!server_.options.token.empty() && queryValue(target, "token") != server_.options.token)
        return reply(http::status::forbidden, "a token is needed\n", "text/plain");
      // Without a token, only a page that names this machine may talk to it:
      // one served from a name that rebinds to 127.0.0.1 sends its own name.
      const std::string host(req_[http::field::host]);
      if (server_.options.token.empty() && !isOwnHost(host, server_.options.address))
        return reply(http::status::forbidden, "wrong host: open the viewer as http://127.0.0.1 or http://localhost\n",
                     "text/plain");
      // A browser names the page behind a WebSocket or a cross-origin
      // request; only this server's own pages may.
      const std::string origin(req_[http::field::origin]);
      if (!origin.empty() && origin != "http://" + host)
        return reply(http::status::forbidden, "wrong origin\n", "text/plain");
      if (websocket::is_upgrade(req_)) {
        std::make_shared<WsSession>(server_, stream_.release_socket())->start(std::move(req_));
        return;
      }
      if (req_.method() != http::verb::get && req_.method() != http::verb::head)
        return reply(http::status::method_not_allowed, "GET only\n", "text/plain");
      std::string path = target.substr(0, target.find('?'));
      if (path.empty() || path[0] != '/' || path.find("..") != std::string::npos || path.find('\\') != std::string::npos ||
          path.find('%') != std::string::npos || path.find('\0') != std::string::npos)
        return reply(http::status::bad_request, "bad path\n", "text/plain");
      if (path.back() == '/') path += "index.html";
      std::error_code ec;
      const fs::path file = fs::weakly_canonical(server_.root / path.substr(1), ec);
      const std::string rootText = server_.root.string() + "/";
      if (ec || file.string().rfind(rootText, 0) != 0 || !fs::is_regular_file(file, ec))
        return reply(http::status::not_found, "not found\n", "text/plain");
      std::ifstream in(file, std::ios::binary);
      std::ostringstream body;
      body << in.rdbuf();
      reply(http::status::ok, body.str(), contentType(file));
    }
  };

  void accept() {
    acceptor.async_accept(net::make_strand(ioc), [this](beast::error_code ec, tcp::socket socket) {
      if (ec) return;  // closed: the server is stopping
      // An image goes out in several segments; with Nagle's algorithm the
      // last one would wait for the browser's delayed acknowledgement (tens
      // of milliseconds on every image).
      beast::error_code nec;
      socket.set_option(tcp::no_delay(true), nec);
      std::make_shared<HttpSession>(*this, std::move(socket))->start();
      accept();
    });
  }
};

Server::Server(const ServerOptions& options) : impl_(std::make_shared<Impl>()) {
  impl_->options = options;
  if (!isLoopback(options.address) && options.token.empty())
    throw InputError(fmt::format("viewer: binding {} (not loopback) needs a token, which the URL then carries",
                                 options.address));
  std::error_code fec;
  impl_->root = fs::canonical(options.root, fec);
  if (fec || !fs::is_directory(impl_->root)) throw InputError(fmt::format("viewer: {}: no such folder", options.root));
  boost::system::error_code ec;
  const auto address = net::ip::make_address(options.address, ec);
  if (ec) throw InputError(fmt::format("viewer: '{}' is not an IP address", options.address));
  const tcp::endpoint endpoint(address, static_cast<unsigned short>(options.port));
  impl_->acceptor.open(endpoint.protocol(), ec);
  if (!ec) impl_->acceptor.set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) impl_->acceptor.bind(endpoint, ec);
  if (!ec) impl_->acceptor.listen(net::socket_base::max_listen_connections, ec);
  if (ec) throw InputError(fmt::format("viewer: cannot listen on {}:{}: {}", options.address, options.port, ec.message()));
  impl_->accept();
  impl_->thread = std::thread([impl = impl_.get()] { impl->ioc.run(); });
}

Server::~Server() {
  impl_->ioc.stop();
  if (impl_->thread.joinable()) impl_->thread.join();
}

int Server::port() const { return impl_->acceptor.local_endpoint().port(); }

std::string Server::url() const {
  std::string u = fmt::format("http://{}:{}/", impl_->options.address, port());
  if (!impl_->options.token.empty()) u += "?token=" + impl_->options.token;
  return u;
}

std::size_t Server::clients() const { return impl_->clientCount.load(); }

void Server::publish(int channel, std::string bytes) {
  auto msg = std::make_shared<const std::string>(std::move(bytes));
  net::post(impl_->ioc, [impl = impl_.get(), channel, msg] {
    std::erase_if(impl->sessions, [](const auto& w) { return w.expired(); });
    for (auto& w : impl->sessions)
      if (auto s = w.lock()) s->publish(channel, msg);
  });
}

void Server::onMessage(std::function<std::string(const std::string&)> handler) {
  const std::lock_guard lock(impl_->handlerMutex);
  impl_->handler = std::move(handler);
}

}  // namespace pp5::viewer
