#include "igtl/igtl_server.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <deque>
#include <functional>
#include <set>
#include <tuple>
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
#include <spdlog/spdlog.h>

#include "core/error.hpp"
#include "core/io_util.hpp"
#include "igtl/igtl_codec.hpp"
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

struct Server::Impl {
  ServerOptions options;
  int listenFd = -1;
  int wake[2] = {-1, -1};  // a byte here wakes the loop for new messages
  int port = 0;
  std::atomic<bool> quit{false};
  std::atomic<std::size_t> clientCount{0};
  std::thread thread;

  using Bytes = std::shared_ptr<const std::string>;
  // Under `m`: the newest message of each (type, device), `serial` ordering
  // them; the live volume; replies posted from other threads.
  struct Kept {
    Bytes bytes;                       // null while `pack` has not run
    std::function<std::string()> pack;  // packs it on the server's thread (publishLater)
    std::uint64_t serial = 0;
  };
  struct LiveVolume {
    std::string device;
    Index3 dims{0};
    Mat4 pixelToFrame{1.0};
    std::shared_ptr<const std::vector<std::uint8_t>> voxels;
    std::vector<std::uint64_t> brickSerial;  // the serial of each brick's last change
    std::uint64_t serial = 0;                // of the newest change
    std::uint64_t geometry = 0;              // counts changes of device, size or geometry
    double timeS = 0.0;
  };
  std::mutex m;
  std::map<std::pair<std::string, std::string>, Kept> latest;
  LiveVolume volume;
  std::uint64_t serial = 0;
  std::vector<std::pair<std::uint64_t, Bytes>> posted;  // (client id, reply)
  std::mutex handlerMutex;  // held while the handler runs, and to replace it
  CommandHandler handler;

  struct Client {
    std::uint64_t id = 0;
    int fd = -1;
    std::string peer;                                       // "127.0.0.1:54321", for the log
    MessageReader reader{0};
    Bytes out;                                              // the message being written (shared, not copied) ...
    std::size_t outAt = 0;                                  // ... from here on
    std::map<std::pair<std::string, std::string>, std::uint64_t> sent;  // serial of each kind sent
    std::deque<Bytes> replies;                              // answers, in order
    std::deque<Bytes> volumeParts;                          // the volume update being sent
    std::uint64_t volumeSent = 0;                           // the volume serial it has (0: none)
    std::uint64_t volumeGeometry = 0;
    std::deque<std::chrono::steady_clock::time_point> commandTimes;  // within the last second
    bool closed = false;
  };
  std::vector<Client> clients;
  std::uint64_t nextId = 0;
  std::set<std::pair<std::string, std::string>> unsendable;  // kinds whose packing failed, logged once

  void listen() {
    listenFd = listenTcp(options.address, options.port, 16, port, "OpenIGTLink server");
    if (::pipe2(wake, O_CLOEXEC | O_NONBLOCK) != 0)
      throw InputError(fmt::format("OpenIGTLink server: cannot make its wake-up pipe: {}", std::strerror(errno)));
  }

  void wakeUp() {
    const char b = 1;
    (void)!::write(wake[1], &b, 1);
  }

  // The volume's update for `c`: whole when it has none or the geometry
  // changed, else a sub-volume for each run of changed bricks along x.
  void packVolume(Client& c, const LiveVolume& v, const std::vector<std::uint64_t>& brickSerial) {
    const std::uint8_t* voxels = v.voxels->data();
    const bool whole = c.volumeSent == 0 || c.volumeGeometry != v.geometry;
    if (whole) {
      c.volumeParts.push_back(std::make_shared<const std::string>(
          wire::packCentredImage(v.device, v.dims, voxels, v.pixelToFrame, v.timeS)));
    } else {
      const Index3 nb = bricks(v.dims);
      const std::int64_t b = kVolumeBrick;
      for (std::int64_t k = 0; k < nb.z; ++k)
        for (std::int64_t j = 0; j < nb.y; ++j)
          for (std::int64_t i = 0; i < nb.x;) {
            const auto changed = [&](std::int64_t x) { return brickSerial[static_cast<std::size_t>((k * nb.y + j) * nb.x + x)] > c.volumeSent; };
            if (!changed(i)) {
              ++i;
              continue;
            }
            std::int64_t e = i;
            while (e < nb.x && changed(e)) ++e;
            const Index3 lo(i * b, j * b, k * b);
            const Index3 hi = glm::min(Index3(e * b, (j + 1) * b, (k + 1) * b), v.dims);
            c.volumeParts.push_back(std::make_shared<const std::string>(
                wire::packSubVolume(v.device, v.dims, voxels, v.pixelToFrame, lo, hi - lo, v.timeS)));
            i = e;
          }
    }
    c.volumeSent = v.serial;
    c.volumeGeometry = v.geometry;
  }

  // The newest message of (type, device): packed, or to be packed here.
  void keep(const std::string& type, const std::string& device, Bytes bytes, std::function<std::string()> pack) {
    {
      const std::lock_guard lock(m);
      Kept& k = latest[{type, device}];
      k.bytes = std::move(bytes);
      k.pack = std::move(pack);
      k.serial = ++serial;
    }
    wakeUp();
  }

  // The messages published to be packed here, off the publisher's thread;
  // one replaced before its turn is never packed.
  void packPending() {
    std::vector<std::tuple<std::pair<std::string, std::string>, std::uint64_t, std::function<std::string()>>> todo;
    {
      const std::lock_guard lock(m);
      for (auto& [k, v] : latest)
        if (v.pack) todo.emplace_back(k, v.serial, std::move(v.pack)), v.pack = nullptr;
    }
    for (auto& [key, serialOf, pack] : todo) {
      Bytes bytes;
      try {
        bytes = std::make_shared<const std::string>(pack());
      } catch (const InputError& e) {
        if (unsendable.insert(key).second)
          spdlog::warn("igtl: a {} '{}' cannot be sent ({}); such messages are not sent", key.first, key.second, e.what());
        continue;
      }
      const std::lock_guard lock(m);
      Kept& k = latest[key];
      if (k.serial == serialOf) k.bytes = std::move(bytes);
    }
  }

  // What `c` gets next into c.out: its replies first, then the volume update
  // under way, then the oldest kind it has not had the newest of.
  void fill(Client& c) {
    if (c.out) return;
    c.outAt = 0;
    std::unique_lock lock(m);
    for (auto it = posted.begin(); it != posted.end();)
      if (Client* to = find(it->first)) {
        to->replies.push_back(std::move(it->second));
        it = posted.erase(it);
      } else {
        it = posted.erase(it);  // its client has gone
      }
    for (std::deque<Bytes>* q : {&c.replies, &c.volumeParts})
      if (!q->empty()) {
        c.out = std::move(q->front());
        q->pop_front();
        return;
      }
    const Kept* next = nullptr;
    const std::pair<std::string, std::string>* key = nullptr;
    for (const auto& [k, v] : latest) {
      if (!v.bytes) continue;  // not packed yet
      const auto it = c.sent.find(k);
      if (it != c.sent.end() && it->second >= v.serial) continue;
      if (!next || v.serial < next->serial) next = &v, key = &k;
    }
    if (volume.voxels && volume.serial > c.volumeSent && (!next || volume.serial < next->serial)) {
      const LiveVolume v = volume;  // shares the voxels; the packing is done unlocked
      lock.unlock();
      packVolume(c, v, v.brickSerial);
      if (!c.volumeParts.empty()) {
        c.out = std::move(c.volumeParts.front());
        c.volumeParts.pop_front();
      }
      return;
    }
    if (!next) return;
    c.sent[*key] = next->serial;
    c.out = next->bytes;
  }

  Client* find(std::uint64_t id) {
    for (Client& c : clients)
      if (c.id == id) return &c;
    return nullptr;
  }

  static void reply(Client& c, std::string bytes) { c.replies.push_back(std::make_shared<const std::string>(std::move(bytes))); }

  void command(Client& c, const Incoming& msg) {
    Command head;
    try {
      head = commandOf(msg);
    } catch (const InputError& e) {
      spdlog::warn("igtl: {}: {}", c.peer, e.what());
      reply(c, packStatus(codec::kStatusUnknownInstruction, msg.device, "BAD_COMMAND", e.what()));
      return;
    }
    const auto now = std::chrono::steady_clock::now();
    while (!c.commandTimes.empty() && now - c.commandTimes.front() > std::chrono::seconds(1)) c.commandTimes.pop_front();
    if (static_cast<int>(c.commandTimes.size()) >= options.commandsPerSecond) {
      reply(c, packCommandReply(head, false, fmt::format("more than {} commands a second; this one was not run",
                                                         options.commandsPerSecond)));
      return;
    }
    c.commandTimes.push_back(now);
    Command cmd;
    try {
      cmd = parseCommand(msg);
    } catch (const InputError& e) {
      spdlog::warn("igtl: {}: {}", c.peer, e.what());
      reply(c, packCommandReply(head, false, e.what()));
      return;
    }
    // The handler runs under its own lock, so that once onCommand() has
    // replaced it no call of the old one is under way.
    const std::lock_guard handling(handlerMutex);
    const CommandHandler& h = handler;
    if (!h) {
      reply(c, packCommandReply(cmd, false, fmt::format("{}: this server runs no commands", cmd.name)));
      return;
    }
    const std::weak_ptr<Impl> self = weakSelf;
    const std::uint64_t id = c.id;
    Command form = cmd;  // what the reply needs
    form.attributes.clear();
    h(cmd, [self, id, form](bool ok, const std::string& message) {
      if (const auto impl = self.lock()) {
        {
          const std::lock_guard lock(impl->m);
          impl->posted.emplace_back(id, std::make_shared<const std::string>(packCommandReply(form, ok, message)));
        }
        impl->wakeUp();
      }
    });
  }

  // The answer to one whole message from a client.
  void answer(Client& c, const Incoming& msg) {
    const std::string& type = msg.type;
    const std::string& device = msg.device;
    if (isCommand(msg)) {
      command(c, msg);
    } else if (type == "GET_CAPABIL") {
      std::vector<std::string> types = {"CAPABILITY", "STATUS", "STRING", "RTS_COMMAND"};
      {
        const std::lock_guard lock(m);
        if (volume.voxels) types.emplace_back("IMAGE");
        for (const auto& [k, v] : latest)
          if (std::find(types.begin(), types.end(), k.first) == types.end()) types.push_back(k.first);
      }
      for (const char* get : {"GET_CAPABIL", "GET_STATUS", "GET_IMAGE", "GET_TRANS", "COMMAND"}) types.emplace_back(get);
      reply(c, packCapability(device, types));
    } else if (type == "GET_STATUS") {
      reply(c, packStatus(codec::kStatusOk, device, "", "pp5echo is running"));
    } else if (type == "GET_IMAGE" || type == "GET_TRANS") {
      // The newest message of that type and device (every device when none is named).
      const std::string wanted = type == "GET_IMAGE" ? "IMAGE" : "TRANSFORM";
      std::vector<Bytes> found;
      bool theVolume = false;
      {
        const std::lock_guard lock(m);
        for (const auto& [k, v] : latest)
          if (k.first == wanted && (device.empty() || k.second == device) && v.bytes) found.push_back(v.bytes);
        theVolume = wanted == "IMAGE" && volume.voxels && (device.empty() || device == volume.device);
      }
      if (theVolume) c.volumeSent = 0;  // the whole volume comes next
      if (found.empty() && !theVolume)
        reply(c, packStatus(codec::kStatusNotFound, device, "NOT_FOUND",
                            fmt::format("pp5echo has no {} named '{}' (yet)", wanted, device)));
      for (auto& f : found) c.replies.push_back(std::move(f));
    } else if (type == "STATUS" || type.rfind("STT_", 0) == 0 || type.rfind("STP_", 0) == 0) {
      // A client's own status, or a stream start/stop pp5echo does not offer: noted, not answered.
    } else {
      reply(c, packStatus(codec::kStatusUnknownInstruction, device, "UNKNOWN_INSTRUCTION",
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
    try {
      for (const Incoming& msg : c.reader.feed(buf, static_cast<std::size_t>(n))) answer(c, msg);
    } catch (const InputError& e) {
      spdlog::warn("igtl: {}: {}; connection closed", c.peer, e.what());
      c.closed = true;
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

  void accept() {
    for (int fd; (fd = ::accept4(listenFd, nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK)) >= 0;) {
      const int one = 1;  // each message as soon as it is written
      ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      Client c;
      c.id = ++nextId;
      c.fd = fd;
      c.reader = MessageReader(options.maxMessageBytes);
      sockaddr_in a{};
      socklen_t len = sizeof a;
      char text[INET_ADDRSTRLEN] = "?";
      if (::getpeername(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0) ::inet_ntop(AF_INET, &a.sin_addr, text, sizeof text);
      c.peer = fmt::format("client {}:{}", text, ntohs(a.sin_port));
      clients.push_back(std::move(c));  // gets the newest of every kind at the next turn
    }
  }

  void run() {
    // On quit, what is pending (the final volume) still goes out, for up to 2 s.
    std::chrono::steady_clock::time_point flushUntil{};
    while (true) {
      packPending();
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
      if (fds[0].revents & POLLIN) accept();
      clientCount = clients.size();
    }
    for (Client& c : clients) ::close(c.fd);
    clients.clear();
    clientCount = 0;
  }

  std::weak_ptr<Impl> weakSelf;
};

Server::Server(const ServerOptions& options) : impl_(std::make_shared<Impl>()) {
  impl_->options = options;
  impl_->weakSelf = impl_;
  impl_->listen();
  impl_->thread = std::thread([impl = impl_.get()] { impl->run(); });
}

Server::~Server() {
  impl_->quit = true;
  impl_->wakeUp();
  if (impl_->thread.joinable()) impl_->thread.join();
  for (const int fd : {impl_->listenFd, impl_->wake[0], impl_->wake[1]})
    if (fd >= 0) ::close(fd);
  impl_->wake[1] = -1;
}

int Server::port() const { return impl_->port; }
std::size_t Server::clients() const { return impl_->clientCount.load(); }

void Server::onCommand(CommandHandler handler) {
  const std::lock_guard lock(impl_->handlerMutex);
  impl_->handler = std::move(handler);
}

Index3 Server::bricks(const Index3& dims) { return (dims + Index3(kVolumeBrick - 1)) / Index3(kVolumeBrick); }

void Server::publishImage(const std::string& device, const Index3& dims, const std::uint8_t* voxels,
                          const Mat4& pixelToFrame, double timeS, int components) {
  const std::size_t n = static_cast<std::size_t>(dims.x * dims.y * dims.z) * static_cast<std::size_t>(components);
  publishLater("IMAGE", device, [device, dims, pixelToFrame, timeS, components, v = std::vector<std::uint8_t>(voxels, voxels + n)] {
    return wire::packCentredImage(device, dims, v.data(), pixelToFrame, timeS, components);
  });
}

void Server::publishLater(const std::string& type, const std::string& device, std::function<std::string()> pack) {
  impl_->keep(type, device, nullptr, std::move(pack));
}

void Server::publishVolume(const std::string& device, const Index3& dims,
                           std::shared_ptr<const std::vector<std::uint8_t>> voxels, const Mat4& pixelToFrame,
                           const std::vector<std::uint8_t>& changed, double timeS) {
  const Index3 nb = bricks(dims);
  const std::size_t n = static_cast<std::size_t>(nb.x * nb.y * nb.z);
  if (!voxels || voxels->size() != static_cast<std::size_t>(dims.x * dims.y * dims.z) || (!changed.empty() && changed.size() != n))
    throw InvariantError("publishVolume: voxels or the changed bricks do not match the volume's size");
  {
    const std::lock_guard lock(impl_->m);
    Impl::LiveVolume& v = impl_->volume;
    const bool geometry = v.device != device || v.dims != dims || v.pixelToFrame != pixelToFrame;
    if (geometry) {
      ++v.geometry;
      v.device = device;
      v.dims = dims;
      v.pixelToFrame = pixelToFrame;
      v.brickSerial.assign(n, 0);
    }
    const std::uint64_t s = impl_->serial + 1;
    bool any = geometry;
    for (std::size_t i = 0; i < n; ++i)
      if (changed.empty() || changed[i]) v.brickSerial[i] = s, any = true;
    v.voxels = std::move(voxels);
    v.timeS = timeS;
    if (!any) return;
    v.serial = impl_->serial = s;
  }
  impl_->wakeUp();
}

void Server::publish(const std::string& type, const std::string& device, std::string bytes) {
  impl_->keep(type, device, std::make_shared<const std::string>(std::move(bytes)), nullptr);
}

}  // namespace pp5::igtl
