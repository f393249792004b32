// The live viewer's server (src/viewer): static files, WebSockets that carry
// only the newest message to a slow client, control messages with error
// replies, and the security rules (loopback or a token, the Origin, no path
// traversal, bounded messages), against a real client on 127.0.0.1.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdint>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>

#include <unistd.h>

#include "core/error.hpp"
#include "viewer/jpeg.hpp"
#include "viewer/viewer_server.hpp"
#include "ws_client.hpp"

namespace {

namespace fs = std::filesystem;
namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = net::ip::tcp;
using pp5::test::Client;
using pp5::viewer::Server;
using pp5::viewer::ServerOptions;

fs::path webRoot() {
  const fs::path d = fs::temp_directory_path() / ("pp5_viewer_" + std::to_string(::getpid()));
  fs::create_directories(d / "css");
  std::ofstream(d / "index.html") << "<html>pp5echo</html>";
  std::ofstream(d / "css" / "a.css") << "body{}";
  std::ofstream(d.parent_path() / ("pp5_secret_" + std::to_string(::getpid()))) << "secret";
  return d;
}

ServerOptions options() {
  ServerOptions o;
  o.root = webRoot().string();
  return o;
}

// One HTTP GET to 127.0.0.1: status and body. `host` is the Host header's
// name (a page served from a name that rebinds to 127.0.0.1 sends its own),
// `origin` the Origin header, none when empty.
std::pair<int, std::string> get(int port, const std::string& target, const std::string& host = "127.0.0.1",
                                const std::string& origin = "") {
  net::io_context ioc;
  tcp::resolver resolver(ioc);
  beast::tcp_stream stream(ioc);
  stream.connect(resolver.resolve("127.0.0.1", std::to_string(port)));
  http::request<http::empty_body> req(http::verb::get, target, 11);
  req.set(http::field::host, host + ":" + std::to_string(port));
  if (!origin.empty()) req.set(http::field::origin, origin);
  http::write(stream, req);
  beast::flat_buffer buffer;
  http::response<http::string_body> res;
  http::read(stream, buffer, res);
  return {static_cast<int>(res.result_int()), res.body()};
}

bool waitFor(const std::function<bool()>& f) {
  for (int i = 0; i < 500 && !f(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  return f();
}

TEST(ViewerServer, ServesItsOwnFilesOnly) {
  Server s(options());
  EXPECT_NE(s.url().find("http://127.0.0.1:"), std::string::npos);
  EXPECT_EQ(get(s.port(), "/"), (std::pair<int, std::string>{200, "<html>pp5echo</html>"}));
  EXPECT_EQ(get(s.port(), "/css/a.css").first, 200);
  EXPECT_EQ(get(s.port(), "/missing.html").first, 404);
  // Traversal, plain and encoded, never reaches a file outside the folder.
  const std::string secret = "pp5_secret_" + std::to_string(::getpid());
  for (const std::string& t : {"/../" + secret, "/css/../../" + secret, "/%2e%2e/" + secret, "/..%2f" + secret})
    EXPECT_NE(get(s.port(), t).second, "secret") << t;
  EXPECT_EQ(get(s.port(), "/../" + secret).first, 400);
}

TEST(ViewerServer, NonLoopbackNeedsAToken) {
  ServerOptions o = options();
  o.address = "0.0.0.0";
  try {
    Server s(o);
    FAIL() << "bound every interface without a token";
  } catch (const pp5::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("token"), std::string::npos) << e.what();
  }
  // With a token (on loopback here, so the test stays on this machine) every
  // request must carry it.
  o.address = "127.0.0.1";
  o.token = "k3y";
  Server s(o);
  EXPECT_NE(s.url().find("?token=k3y"), std::string::npos);
  EXPECT_EQ(get(s.port(), "/").first, 403);
  EXPECT_EQ(get(s.port(), "/?token=wrong").first, 403);
  EXPECT_EQ(get(s.port(), "/?token=k3y").first, 200);
  o.root = "/no/such/folder";
  EXPECT_THROW(Server{o}, pp5::InputError);
}

TEST(ViewerServer, WebSocketChecksTheOrigin) {
  Server s(options());
  const std::string own = "http://127.0.0.1:" + std::to_string(s.port());
  Client evil;
  EXPECT_THROW(evil.connect(s.port(), "http://evil.example"), boost::system::system_error);
  Client page;
  page.connect(s.port(), own);
  ASSERT_TRUE(waitFor([&] { return s.clients() == 1; }));
  s.publish(0, "frame");
  EXPECT_EQ(page.read(), "frame");
}

// DNS rebinding: a page from evil.example whose name then resolves to
// 127.0.0.1 reaches the server with Host (and Origin) evil.example. Without a
// token it gets neither the page's data nor a WebSocket; this machine's own
// names do, with any port (an ssh tunnel's).
TEST(ViewerServer, ARebindingPageIsRefused) {
  Server s(options());
  const int port = s.port();
  const std::string evil = "http://evil.example:" + std::to_string(port);
  EXPECT_EQ(get(port, "/", "evil.example").first, 403);
  EXPECT_EQ(get(port, "/", "evil.example", evil).first, 403);
  EXPECT_NE(get(port, "/", "evil.example").second.find("wrong host"), std::string::npos);
  EXPECT_EQ(get(port, "/", "127.0.0.1.evil.example").first, 403);
  EXPECT_EQ(get(port, "/", "").first, 403);
  Client rebound;
  EXPECT_THROW(rebound.connect(port, evil, "/ws", "evil.example"), boost::system::system_error);
  EXPECT_THROW(rebound.connect(port, "", "/ws", "evil.example"), boost::system::system_error);
  for (const std::string& own : {"127.0.0.1", "localhost", "LocalHost", "[::1]"})
    EXPECT_EQ(get(port, "/", own).first, 200) << own;
  // A foreign Origin on a page's own Host (a cross-origin fetch) is refused too.
  EXPECT_EQ(get(port, "/", "127.0.0.1", "http://evil.example").first, 403);
  Client page;
  page.connect(port, "http://localhost:" + std::to_string(port), "/ws", "localhost");
  ASSERT_TRUE(waitFor([&] { return s.clients() == 1; }));
  EXPECT_EQ(s.clients(), 1u);
  // With a token (a server reached by another name) the token is the check.
  ServerOptions o = options();
  o.token = "k3y";
  Server t(o);
  EXPECT_EQ(get(t.port(), "/?token=k3y", "scanner.lab").first, 200);
  EXPECT_EQ(get(t.port(), "/", "scanner.lab").first, 403);
}

// Each client has its own budget of control messages: one that floods it
// gets errors, and another's controls still go through.
TEST(ViewerServer, OneClientCannotSilenceAnother) {
  ServerOptions o = options();
  o.maxMessagesPerSecond = 20;
  Server s(o);
  std::atomic<int> accepted{0}, others{0};
  s.onMessage([&](const std::string& m) -> std::string {
    ++(m == "{\"other\": 1}" ? others : accepted);
    return "";
  });
  Client flood, other;
  flood.connect(s.port(), "");
  other.connect(s.port(), "");
  flood.ws.text(true);
  other.ws.text(true);
  for (int i = 0; i < 60; ++i) flood.ws.write(net::buffer(std::string("{}")));
  // The flood's first 20 pass (at most one second's budget, with the time the
  // 60 take), the rest are answered with the error.
  EXPECT_NE(flood.read().find("too many control messages"), std::string::npos);
  EXPECT_LE(accepted.load(), 40);
  other.ws.write(net::buffer(std::string("{\"other\": 1}")));
  ASSERT_TRUE(waitFor([&] { return others.load() == 1; }));
}

TEST(ViewerServer, ControlMessagesAreCheckedAndBadOnesAnswered) {
  Server s(options());
  std::atomic<int> accepted{0};
  s.onMessage([&](const std::string& m) -> std::string {
    if (m == "{\"view\": 1}") {
      ++accepted;
      return "";
    }
    return "unknown control \"" + m + "\"";
  });
  Client c;
  c.connect(s.port(), "");
  c.ws.text(true);
  c.ws.write(net::buffer(std::string("{\"view\": 1}")));
  c.ws.write(net::buffer(std::string("nonsense")));
  EXPECT_EQ(c.read(), "{\"error\": \"unknown control \\\"nonsense\\\"\"}");
  EXPECT_EQ(accepted.load(), 1);
  // A message over the size limit ends that connection, not the server.
  beast::error_code ec;
  c.ws.write(net::buffer(std::string(70 * 1024, 'x')), ec);  // the server may close while it is written
  beast::flat_buffer b;
  c.ws.read(b, ec);
  EXPECT_TRUE(ec);
  Client d;
  d.connect(s.port(), "");
  // The server counts a client once its side of the handshake is done.
  ASSERT_TRUE(waitFor([&] { return s.clients() == 1; }));
  s.publish(0, "still here");
  EXPECT_EQ(d.read(), "still here");
}

TEST(ViewerServer, ASlowClientGetsTheNewestImageOnly) {
  Server s(options());
  Client c;
  c.connect(s.port(), "");
  ASSERT_TRUE(waitFor([&] { return s.clients() == 1; }));
  // 200 images of 256 kB each while the client reads nothing: the server
  // keeps only the newest unsent one per channel.
  const int n = 200;
  for (int i = 0; i < n; ++i) {
    std::string img(256 * 1024, static_cast<char>('a' + i % 26));
    img.replace(0, std::to_string(i).size(), std::to_string(i));
    s.publish(1, std::move(img));
  }
  s.publish(2, "status");
  int got = 0, last = -1;
  bool status = false;
  while (last != n - 1 || !status) {
    const std::string m = c.read();
    if (m == "status") {
      status = true;
      continue;
    }
    const int i = std::stoi(m.substr(0, 3));
    EXPECT_GT(i, last);  // in order, never an older image after a newer one
    last = i;
    ++got;
  }
  EXPECT_LT(got, n);  // the slow client skipped images
  EXPECT_EQ(last, n - 1);
}

TEST(ViewerServer, ClientsComeAndGo) {
  Server s(options());
  {
    Client a, b;
    a.connect(s.port(), "");
    b.connect(s.port(), "");
    ASSERT_TRUE(waitFor([&] { return s.clients() == 2; }));
    s.publish(0, "both");
    EXPECT_EQ(a.read(), "both");
    EXPECT_EQ(b.read(), "both");
  }
  ASSERT_TRUE(waitFor([&] { return s.clients() == 0; }));
  Client again;
  again.connect(s.port(), "");
  ASSERT_TRUE(waitFor([&] { return s.clients() == 1; }));
  s.publish(0, "resumed");
  EXPECT_EQ(again.read(), "resumed");
}

// JPEG: a smooth image comes back close to its pixels, the size and the
// quality matter, and what is not a JPEG is refused.
TEST(ViewerJpeg, RoundTripIsCloseAndQualityCounts) {
  const int w = 160, h = 96;
  std::string rgb(static_cast<std::size_t>(w) * h * 3, '\0');
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      auto* p = reinterpret_cast<std::uint8_t*>(rgb.data()) + 3 * (y * w + x);
      p[0] = static_cast<std::uint8_t>(x * 255 / (w - 1));
      p[1] = static_cast<std::uint8_t>(y * 255 / (h - 1));
      p[2] = 90;
    }
  pp5::viewer::JpegEncoder enc;
  const auto* px = reinterpret_cast<const std::uint8_t*>(rgb.data());
  const std::string hi = enc.encode(px, w, h, 90), lo = enc.encode(px, w, h, 20);
  EXPECT_EQ(static_cast<unsigned char>(hi[0]), 0xFF);  // SOI
  EXPECT_EQ(static_cast<unsigned char>(hi[1]), 0xD8);
  EXPECT_LT(lo.size(), hi.size());
  const auto d = pp5::viewer::decodeJpeg(hi);
  ASSERT_EQ(d.width, w);
  ASSERT_EQ(d.height, h);
  double se = 0.0;
  for (std::size_t i = 0; i < rgb.size(); ++i) {
    const double e = static_cast<double>(static_cast<std::uint8_t>(d.rgb[i])) - static_cast<std::uint8_t>(rgb[i]);
    se += e * e;
  }
  const double psnr = 10.0 * std::log10(255.0 * 255.0 / (se / static_cast<double>(rgb.size())));
  EXPECT_GT(psnr, 35.0);
  EXPECT_THROW(pp5::viewer::decodeJpeg("not a jpeg"), pp5::InputError);
  EXPECT_THROW(enc.encode(px, w, h, 0), pp5::InvariantError);
}

}  // namespace
