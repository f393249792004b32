#include "igtl/igtl_client.hpp"

#include <fcntl.h>
#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <deque>
#include <map>
#include <thread>
#include <vector>

#include <spdlog/spdlog.h>

#include "core/error.hpp"
#include "igtl/igtl_codec.hpp"
#include "igtl/igtl_wire.hpp"

namespace pp5::igtl {

Endpoint parseIgtlUrl(const std::string& url) {
  static const std::string scheme = "igtl://";
  auto bad = [&](const char* why) -> Endpoint {
    throw InputError(fmt::format("'{}': {} (expected igtl://host:port)", url, why));
  };
  if (url.compare(0, scheme.size(), scheme) != 0) return bad("not an OpenIGTLink URL");
  std::string rest = url.substr(scheme.size());
  if (!rest.empty() && rest.back() == '/') rest.pop_back();  // "igtl://host:port/" is common
  Endpoint e;
  std::string portText;
  if (!rest.empty() && rest.front() == '[') {  // [IPv6]
    const auto close = rest.find(']');
    if (close == std::string::npos) return bad("unclosed '[' in the host");
    e.host = rest.substr(1, close - 1);
    const std::string tail = rest.substr(close + 1);
    if (!tail.empty()) {
      if (tail.front() != ':') return bad("unexpected text after the host");
      portText = tail.substr(1);
      if (portText.empty()) return bad("empty port");
    }
  } else {
    const auto colon = rest.find(':');
    e.host = rest.substr(0, colon);
    if (colon != std::string::npos) {
      portText = rest.substr(colon + 1);
      if (portText.empty()) return bad("empty port");
    }
  }
  if (e.host.empty()) return bad("no host");
  if (e.host.find_first_of("/?#@ \t[]") != std::string::npos) return bad("unexpected character in the host");
  if (!portText.empty()) {
    if (portText.size() > 5 || portText.find_first_not_of("0123456789") != std::string::npos)
      return bad("the port is not a number");
    e.port = std::stoi(portText);
    if (e.port < 1 || e.port > 65535) return bad("the port is outside 1..65535");
  }
  return e;
}

std::string toString(const Endpoint& e) {
  return e.host.find(':') != std::string::npos ? fmt::format("[{}]:{}", e.host, e.port)
                                                : fmt::format("{}:{}", e.host, e.port);
}

namespace {

using Clock = std::chrono::steady_clock;
// How often blocking waits look at the stop flag.
constexpr int kPollMs = 50;
// A message larger than this is taken as a broken stream (a 4k RGBA frame is 33 MB).
constexpr std::uint64_t kMaxBody = std::uint64_t{1} << 30;
// TRANSFORMs kept per device for pairing: two seconds of a 30 Hz tracker.
constexpr std::size_t kHistory = 64;

enum class Status { Ok, Closed, Stopped };

// A plain non-blocking TCP socket with poll(): unlike igtl::ClientSocket it
// bounds the connect time and tells a timeout from a closed connection without
// losing bytes of a half-read message.
class Connection {
public:
  Connection() = default;
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;
  ~Connection() { close(); }

  void close() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

  // An already open stream (a socketpair in tests), read as a connection.
  void adopt(int fd) {
    close();
    fd_ = fd;
  }

  // One attempt, across the host's addresses, until `deadline`.
  Status connect(const Endpoint& ep, Clock::time_point deadline, const std::atomic<bool>& stop, std::string* why) {
    close();
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* list = nullptr;
    const std::string port = std::to_string(ep.port);
    if (const int rc = ::getaddrinfo(ep.host.c_str(), port.c_str(), &hints, &list); rc != 0) {
      *why = fmt::format("cannot resolve host '{}' ({})", ep.host, ::gai_strerror(rc));
      return Status::Closed;
    }
    Status result = Status::Closed;
    for (addrinfo* a = list; a && result == Status::Closed; a = a->ai_next) {
      fd_ = ::socket(a->ai_family, a->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, a->ai_protocol);
      if (fd_ < 0) {
        *why = std::strerror(errno);
        continue;
      }
      if (::connect(fd_, a->ai_addr, a->ai_addrlen) == 0) {
        result = Status::Ok;
        break;
      }
      if (errno != EINPROGRESS) {
        *why = std::strerror(errno);
        close();
        continue;
      }
      result = waitConnected(deadline, stop, why);
      if (result != Status::Ok) close();
    }
    ::freeaddrinfo(list);
    return result;
  }

  Status readExact(void* data, std::size_t n, const std::atomic<bool>& stop, std::string* why) {
    auto* p = static_cast<std::uint8_t*>(data);
    std::size_t got = 0;
    while (got < n) {
      if (stop.load()) return Status::Stopped;
      pollfd pfd{fd_, POLLIN, 0};
      const int rc = ::poll(&pfd, 1, kPollMs);
      if (rc < 0 && errno != EINTR) {
        *why = std::strerror(errno);
        return Status::Closed;
      }
      if (rc <= 0) continue;
      const ssize_t r = ::recv(fd_, p + got, n - got, 0);
      if (r == 0) {
        *why = "the server closed the connection";
        return Status::Closed;
      }
      if (r < 0) {
        if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) continue;
        *why = std::strerror(errno);
        return Status::Closed;
      }
      got += static_cast<std::size_t>(r);
    }
    return Status::Ok;
  }

  Status skip(std::uint64_t n, const std::atomic<bool>& stop, std::string* why) {
    std::vector<std::uint8_t> sink(static_cast<std::size_t>(std::min<std::uint64_t>(n, 1 << 16)));
    while (n > 0) {
      const std::size_t chunk = static_cast<std::size_t>(std::min<std::uint64_t>(n, sink.size()));
      if (const Status s = readExact(sink.data(), chunk, stop, why); s != Status::Ok) return s;
      n -= chunk;
    }
    return Status::Ok;
  }

private:
  Status waitConnected(Clock::time_point deadline, const std::atomic<bool>& stop, std::string* why) {
    for (;;) {
      if (stop.load()) return Status::Stopped;
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
      if (left <= 0) {
        *why = "timed out";
        return Status::Closed;
      }
      pollfd pfd{fd_, POLLOUT, 0};
      const int rc = ::poll(&pfd, 1, static_cast<int>(std::min<long long>(left, kPollMs)));
      if (rc < 0 && errno != EINTR) {
        *why = std::strerror(errno);
        return Status::Closed;
      }
      if (rc <= 0) continue;
      int err = 0;
      socklen_t len = sizeof err;
      if (::getsockopt(fd_, SOL_SOCKET, SO_ERROR, &err, &len) != 0) err = errno;
      if (err != 0) {
        *why = std::strerror(err);
        return Status::Closed;
      }
      return Status::Ok;
    }
  }

  int fd_ = -1;
};

struct StampedMatrix {
  double t;
  Mat4 m;
};

}  // namespace

struct Client::Impl {
  ClientOptions opt;
  std::uint64_t nextIndex = 0;
  // Per TRANSFORM device, most recent last; `devices` keeps first-seen order so
  // a frame's transforms come in the same order every time.
  std::vector<std::string> devices;
  std::map<std::string, std::deque<StampedMatrix>> history;

  std::atomic<std::uint64_t> images{0}, transforms{0}, paired{0}, imagesWithoutPose{0}, skipped{0}, rejected{0}, disconnects{0},
      reconnects{0}, bytes{0};

  // Tries to connect until `timeoutS` has passed, again and again: a server
  // that is starting (or restarting) refuses at first.
  Status connectWithin(Connection& c, double timeoutS, const std::atomic<bool>& stop, std::string* why) {
    const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                             std::chrono::duration<double>(std::max(0.0, timeoutS)));
    for (;;) {
      const Status s = c.connect(opt.endpoint, deadline, stop, why);
      if (s != Status::Closed) return s;
      for (int i = 0; i < 2; ++i) {  // 100 ms between attempts, watching the flag
        if (stop.load()) return Status::Stopped;
        if (Clock::now() >= deadline) return Status::Closed;
        std::this_thread::sleep_for(std::chrono::milliseconds(kPollMs));
      }
    }
  }

  void addTransform(const std::string& device, double t, const Mat4& m) {
    auto [it, fresh] = history.try_emplace(device);
    if (fresh) devices.push_back(device);
    it->second.push_back({t, m});
    if (it->second.size() > kHistory) it->second.pop_front();
  }

  // The nearest TRANSFORM of each device, when within the tolerance. On a tie
  // the later one wins.
  int pair(Frame& f) const {
    int n = 0;
    for (const auto& device : devices) {
      const StampedMatrix* best = nullptr;
      double bestDt = 0.0;
      for (const auto& s : history.at(device)) {
        const double dt = std::abs(s.t - f.timestamp);
        if (dt <= opt.pairToleranceS && (!best || dt <= bestDt)) {
          best = &s;
          bestDt = dt;
        }
      }
      if (best) {
        f.transforms.push_back({wire::transformName(device), best->m, true});
        ++n;
      }
    }
    return n;
  }

  Status receiveOne(Connection& c, const std::function<void(Frame&&)>& onFrame, const std::atomic<bool>& stop,
                    std::string* why) {
    std::uint8_t raw[codec::kHeaderBytes];
    if (const Status s = c.readExact(raw, sizeof raw, stop, why); s != Status::Ok) return s;
    bytes += sizeof raw;
    // After a bad header the message boundaries are lost: treat it as a break.
    codec::Header header;
    try {
      header = codec::readHeader(raw);
    } catch (const InputError& e) {
      *why = fmt::format("a malformed message header ({})", e.what());
      return Status::Closed;
    }
    const std::string& type = header.type;
    const std::string& device = header.device;
    if (header.bodySize > kMaxBody) {
      *why = fmt::format("a {} message from '{}' claims a body of {} bytes", type, device, header.bodySize);
      return Status::Closed;
    }
    const std::size_t bodySize = static_cast<std::size_t>(header.bodySize);
    const bool wantImage = type == "IMAGE" && (opt.imageDevice.empty() || device == opt.imageDevice);
    const bool wantTransform = type == "TRANSFORM";
    if (!wantImage && !wantTransform) {
      ++skipped;
      bytes += bodySize;
      return c.skip(bodySize, stop, why);
    }
    // The body is read in chunks into a buffer that grows with what arrives, so
    // a header that claims a huge body costs memory only as the bytes come
    // (a corrupt or hostile header once made the client allocate 1 GiB).
    std::string body;
    while (body.size() < bodySize) {
      const std::size_t chunk = std::min<std::size_t>(bodySize - body.size(), std::size_t{1} << 20);
      const std::size_t at = body.size();
      body.resize(at + chunk);
      if (const Status s = c.readExact(reinterpret_cast<std::uint8_t*>(body.data()) + at, chunk, stop, why); s != Status::Ok)
        return s;
    }
    bytes += bodySize;
    if (codec::crc64(reinterpret_cast<const std::uint8_t*>(body.data()), body.size()) != header.crc) {
      spdlog::warn("igtl: dropped a {} message from '{}' (bad CRC)", type, device);  // this one message only
      ++skipped;
      return Status::Ok;
    }
    std::string content;
    codec::Image im;
    try {
      content = codec::readBody(header.version, body).content;  // OpenIGTLink 3 peers send version 2 bodies
      if (wantTransform) {
        if (content.size() != codec::kTransformBytes)
          throw InputError(fmt::format("a TRANSFORM of {} bytes (48 expected)", content.size()));
        addTransform(device, wire::decodeTime(header.time), wire::transformOf(content));
        ++transforms;
        return Status::Ok;
      }
      im = codec::readImage(content);
    } catch (const InputError& e) {
      if (wantImage && rejected++ < 5) spdlog::warn("igtl: skipped an IMAGE from '{}': {}", device, e.what());
      ++skipped;
      return Status::Ok;
    }

    Frame f;
    try {
      wire::imageToFrame(im, content, device, header.time, f);
    } catch (const InputError& e) {
      // An image a Frame cannot hold (RGB, a size that does not match its
      // data): skipped and counted, never the end of the scan.
      if (rejected++ < 5) spdlog::warn("igtl: skipped an IMAGE: {}", e.what());
      ++skipped;
      return Status::Ok;
    }
    f.index = nextIndex++;
    const int n = pair(f);
    paired += static_cast<std::uint64_t>(n);
    const std::string frameName = wire::imageFrameName(device);
    if (!frameName.empty()) f.transforms.push_back({"ImageTo" + frameName, wire::imagePixelToFrame(im), true});
    if (n == 0 && frameName.empty()) ++imagesWithoutPose;
    ++images;
    onFrame(std::move(f));
    return Status::Ok;
  }
};

Client::Client(ClientOptions opt) : impl_(std::make_unique<Impl>()) { impl_->opt = std::move(opt); }
Client::~Client() = default;

void Client::run(const std::function<void(Frame&&)>& onFrame, const std::atomic<bool>& stop) {
  Impl& s = *impl_;
  const std::string where = toString(s.opt.endpoint);
  Connection conn;
  std::string why;
  const Status first = s.connectWithin(conn, s.opt.connectTimeoutS, stop, &why);
  if (first == Status::Stopped) return;
  if (first != Status::Ok)
    throw DeviceError(fmt::format("igtl://{}: cannot connect within {} s: {}", where, s.opt.connectTimeoutS, why));
  spdlog::info("igtl: connected to {}", where);

  for (;;) {
    const Status r = s.receiveOne(conn, onFrame, stop, &why);
    if (r == Status::Stopped) return;
    if (r == Status::Ok) continue;
    conn.close();
    ++s.disconnects;
    if (!s.opt.reconnect) {
      spdlog::warn("igtl: lost {} ({}); not reconnecting", where, why);
      return;
    }
    spdlog::warn("igtl: lost {} ({}); reconnecting for up to {} s", where, why, s.opt.reconnectTimeoutS);
    const Status again = s.connectWithin(conn, s.opt.reconnectTimeoutS, stop, &why);
    if (again == Status::Stopped) return;
    if (again != Status::Ok) {
      spdlog::warn("igtl: {} did not come back within {} s ({}); ending the stream after {} frames", where,
                   s.opt.reconnectTimeoutS, why, s.images.load());
      return;
    }
    ++s.reconnects;
    spdlog::warn("igtl: reconnected to {}", where);
  }
}

void Client::decode(int fd, const std::function<void(Frame&&)>& onFrame) {
  Connection conn;
  conn.adopt(fd);
  std::atomic<bool> stop{false};
  std::string why;
  while (impl_->receiveOne(conn, onFrame, stop, &why) == Status::Ok) {
  }
}

ClientStats Client::stats() const {
  const Impl& s = *impl_;
  ClientStats r;
  r.images = s.images.load();
  r.transforms = s.transforms.load();
  r.paired = s.paired.load();
  r.imagesWithoutPose = s.imagesWithoutPose.load();
  r.skipped = s.skipped.load();
  r.rejected = s.rejected.load();
  r.disconnects = s.disconnects.load();
  r.reconnects = s.reconnects.load();
  r.bytes = s.bytes.load();
  return r;
}

}  // namespace pp5::igtl
