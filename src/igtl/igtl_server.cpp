#include "igtl/igtl_server.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <igtlCapabilityMessage.h>
#include <igtlStatusMessage.h>
#include <igtl_header.h>

#include "core/error.hpp"
#include "core/io_util.hpp"
#include "igtl/igtl_wire.hpp"

namespace pp5::igtl {

void parseServeAddress(const std::string& text, const std::string& key, std::string& address, int& port) {
  io::parseListen(text, address, port, key);
  in_addr a{};
  if (::inet_pton(AF_INET, address.c_str(), &a) != 1)
    throw InputError(fmt::format("{} = \"{}\": '{}' is not an IPv4 address", key, text, address));
}

int listenTcp(const std::string& address, int port, int backlog, int& boundPort, const std::string& what) {
  sockaddr_in a{};
  a.sin_family = AF_INET;
  if (::inet_pton(AF_INET, address.c_str(), &a.sin_addr) != 1)
    throw InputError(fmt::format("{}: '{}' is not an IPv4 address", what, address));
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
  const int one = 1;
  if (fd < 0 || ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one) != 0 ||
      ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || ::listen(fd, backlog) != 0) {
    const std::string why = std::strerror(errno);
    if (fd >= 0) ::close(fd);
    throw InputError(fmt::format("{}: cannot listen on {}:{}: {}", what, address, port, why));
  }
  socklen_t len = sizeof a;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  boundPort = ntohs(a.sin_port);
  return fd;
}

namespace {

std::uint64_t bigEndian64(const std::uint8_t* p) {
  std::uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v = (v << 8) | p[i];
  return v;
}

std::string field(const std::uint8_t* p, std::size_t n) {
  std::size_t len = 0;
  while (len < n && p[len] != 0) ++len;
  return {reinterpret_cast<const char*>(p), len};
}

std::string packed(::igtl::MessageBase& m) {
  m.Pack();
  return {static_cast<const char*>(m.GetPackPointer()), static_cast<std::size_t>(m.GetPackSize())};
}

std::string status(int code, const std::string& device, const std::string& errorName, const std::string& text) {
  auto s = ::igtl::StatusMessage::New();
  s->SetDeviceName(device.c_str());
  s->SetCode(code);
  s->SetSubCode(0);
  s->SetErrorName(errorName.substr(0, 19).c_str());  // a 20-byte field
  s->SetStatusString(text.c_str());
  return packed(*s);
}

}  // namespace

struct Server::Impl {
  ServerOptions options;
  int listenFd = -1;
  int wake[2] = {-1, -1};  // a byte here wakes the loop for new messages
  int port = 0;
  std::atomic<bool> quit{false};
  std::atomic<std::size_t> clientCount{0};
  std::thread thread;

  // The newest message of each (type, device); `serial` orders them.
  struct Kept {
    std::shared_ptr<const std::string> bytes;
    std::uint64_t serial = 0;
  };
  std::mutex m;
  std::map<std::pair<std::string, std::string>, Kept> latest;
  std::uint64_t serial = 0;

  struct Client {
    int fd = -1;
    std::vector<std::uint8_t> in;
    std::shared_ptr<const std::string> out;                 // the message being written (shared, not copied) ...
    std::size_t outAt = 0;                                  // ... from here on
    std::map<std::pair<std::string, std::string>, std::uint64_t> sent;  // serial of each kind sent
    std::vector<std::shared_ptr<const std::string>> replies;  // answers, in order
    bool closed = false;
  };
  std::vector<Client> clients;

  void listen() {
    listenFd = listenTcp(options.address, options.port, 16, port, "OpenIGTLink server");
    if (::pipe2(wake, O_CLOEXEC | O_NONBLOCK) != 0)
      throw InputError(fmt::format("OpenIGTLink server: cannot make its wake-up pipe: {}", std::strerror(errno)));
  }

  // What `c` still has to get, newest of each kind, into c.out (replies first).
  void fill(Client& c) {
    if (c.out) return;
    c.outAt = 0;
    if (!c.replies.empty()) {
      c.out = std::move(c.replies.front());
      c.replies.erase(c.replies.begin());
      return;
    }
    const std::lock_guard lock(m);
    const Kept* next = nullptr;
    const std::pair<std::string, std::string>* key = nullptr;
    for (const auto& [k, v] : latest) {
      const auto it = c.sent.find(k);
      if (it != c.sent.end() && it->second >= v.serial) continue;
      if (!next || v.serial < next->serial) next = &v, key = &k;
    }
    if (!next) return;
    c.sent[*key] = next->serial;
    c.out = next->bytes;
  }

  static void reply(Client& c, std::string bytes) {
    c.replies.push_back(std::make_shared<const std::string>(std::move(bytes)));
  }

  // The answer to one whole message from a client.
  void answer(Client& c, const std::string& type, const std::string& device) {
    if (type == "GET_CAPABIL") {
      auto cap = ::igtl::CapabilityMessage::New();
      cap->SetDeviceName(device.c_str());
      std::vector<std::string> types = {"CAPABILITY", "STATUS"};
      {
        const std::lock_guard lock(m);
        for (const auto& [k, v] : latest)
          if (std::find(types.begin(), types.end(), k.first) == types.end()) types.push_back(k.first);
      }
      for (const char* get : {"GET_CAPABIL", "GET_STATUS", "GET_IMAGE", "GET_TRANSFORM"}) types.emplace_back(get);
      cap->SetTypes(types);
      reply(c, packed(*cap));
    } else if (type == "GET_STATUS") {
      reply(c, status(::igtl::StatusMessage::STATUS_OK, device, "", "pp5echo is running"));
    } else if (type.rfind("GET_", 0) == 0) {
      // The newest message of that type and device (any device when none is named).
      const std::string wanted = type.substr(4);
      std::vector<std::shared_ptr<const std::string>> found;
      {
        const std::lock_guard lock(m);
        for (const auto& [k, v] : latest)
          if (k.first == wanted && (device.empty() || k.second == device)) found.push_back(v.bytes);
      }
      if (found.empty())
        reply(c, status(::igtl::StatusMessage::STATUS_NOT_FOUND, device, "NOT_FOUND",
                        fmt::format("pp5echo has no {} named '{}' (yet)", wanted, device)));
      for (auto& f : found) c.replies.push_back(std::move(f));
    } else if (type == "STATUS" || type.rfind("STT_", 0) == 0 || type.rfind("STP_", 0) == 0) {
      // A client's own status, or a stream start/stop pp5echo does not offer: noted, not answered.
    } else {
      reply(c, status(::igtl::StatusMessage::STATUS_UNKNOWN_INSTRUCTION, device, "UNKNOWN_INSTRUCTION",
                      fmt::format("pp5echo does not handle {} messages", type)));
    }
  }

  void readFrom(Client& c) {
    std::uint8_t buf[65536];
    const ssize_t n = ::recv(c.fd, buf, sizeof buf, 0);
    if (n == 0 || (n < 0 && errno != EAGAIN && errno != EINTR)) {
      c.closed = true;
      return;
    }
    if (n < 0) return;
    c.in.insert(c.in.end(), buf, buf + n);
    while (c.in.size() >= IGTL_HEADER_SIZE) {
      const std::uint64_t body = bigEndian64(c.in.data() + 42);  // after version, type, device, timestamp
      if (body > options.maxMessageBytes) {
        c.closed = true;  // too large: the connection ends, the server goes on
        return;
      }
      if (c.in.size() < IGTL_HEADER_SIZE + body) return;
      const std::string type = field(c.in.data() + 2, 12), device = field(c.in.data() + 14, 20);
      c.in.erase(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(IGTL_HEADER_SIZE + body));
      answer(c, type, device);
    }
  }

  void writeTo(Client& c) {
    fill(c);
    while (c.out) {
      const ssize_t n = ::send(c.fd, c.out->data() + c.outAt, c.out->size() - c.outAt, MSG_NOSIGNAL);
      if (n < 0 && (errno == EAGAIN || errno == EINTR)) return;
      if (n <= 0) {
        c.closed = true;
        return;
      }
      c.outAt += static_cast<std::size_t>(n);
      if (c.outAt == c.out->size()) c.out.reset();
      fill(c);
    }
  }

  // Whether any client still has something to get.
  bool pending() {
    for (Client& c : clients) {
      fill(c);
      if (c.out) return true;
    }
    return false;
  }

  void run() {
    // On quit, what is pending (the final volume) still goes out, for up to 2 s.
    std::chrono::steady_clock::time_point flushUntil{};
    while (true) {
      if (quit) {
        if (flushUntil == std::chrono::steady_clock::time_point{})
          flushUntil = std::chrono::steady_clock::now() + std::chrono::seconds(2);
        if (!pending() || std::chrono::steady_clock::now() > flushUntil) break;
      }
      std::vector<pollfd> fds = {{listenFd, POLLIN, 0}, {wake[0], POLLIN, 0}};
      for (Client& c : clients) {
        fill(c);
        fds.push_back({c.fd, static_cast<short>(POLLIN | (c.out ? POLLOUT : 0)), 0});
      }
      if (::poll(fds.data(), fds.size(), 200) < 0 && errno != EINTR) break;
      if (fds[1].revents & POLLIN) {
        char drain[256];
        while (::read(wake[0], drain, sizeof drain) > 0) {
        }
      }
      for (std::size_t i = 0; i < clients.size(); ++i) {
        Client& c = clients[i];
        const short ev = fds[i + 2].revents;
        if (ev & (POLLIN | POLLHUP | POLLERR)) readFrom(c);
        if (!c.closed) writeTo(c);
      }
      std::erase_if(clients, [](const Client& c) {
        if (c.closed) ::close(c.fd);
        return c.closed;
      });
      if (fds[0].revents & POLLIN)
        for (int fd; (fd = ::accept4(listenFd, nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK)) >= 0;) {
          const int one = 1;  // each message as soon as it is written
          ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
          Client c;
          c.fd = fd;
          clients.push_back(std::move(c));  // gets the newest of every kind at the next turn
        }
      clientCount = clients.size();
    }
    for (Client& c : clients) ::close(c.fd);
    clients.clear();
    clientCount = 0;
  }
};

Server::Server(const ServerOptions& options) : impl_(std::make_unique<Impl>()) {
  impl_->options = options;
  impl_->listen();
  impl_->thread = std::thread([impl = impl_.get()] { impl->run(); });
}

Server::~Server() {
  impl_->quit = true;
  const char b = 1;
  (void)!::write(impl_->wake[1], &b, 1);
  if (impl_->thread.joinable()) impl_->thread.join();
  for (const int fd : {impl_->listenFd, impl_->wake[0], impl_->wake[1]})
    if (fd >= 0) ::close(fd);
}

int Server::port() const { return impl_->port; }
std::size_t Server::clients() const { return impl_->clientCount.load(); }

void Server::publishImage(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                          const Mat4& pixelToFrame, double timeS) {
  publish("IMAGE", device, wire::packCentredImage(device, dims, voxels, pixelToFrame, timeS));
}

void Server::publish(const std::string& type, const std::string& device, std::string bytes) {
  {
    const std::lock_guard lock(impl_->m);
    Impl::Kept& k = impl_->latest[{type, device}];
    k.bytes = std::make_shared<const std::string>(std::move(bytes));
    k.serial = ++impl_->serial;
  }
  const char b = 1;
  (void)!::write(impl_->wake[1], &b, 1);
}

}  // namespace pp5::igtl
