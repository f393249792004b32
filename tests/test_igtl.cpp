// The OpenIGTLink live source against pp5echo-igtl-server: exact frames and
// poses, the image matrix of Image_<Frame> devices, pairing tolerance, a server
// that vanishes (and comes back), a refused connection and the stop flag.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>

#include "core/error.hpp"
#include "formats/sequence_io.hpp"
#include "igtl/igtl_client.hpp"

#include <igtlImageMessage.h>
#include "io_test_util.hpp"

extern char** environ;

namespace pp5::igtl {
namespace {

using Clock = std::chrono::steady_clock;
using pp5::test::TempDir;

double secondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// The rounding a TRANSFORM message applies, computed here independently.
Mat4 floatRounded(const Mat4& m) {
  Mat4 r;
  for (int c = 0; c < 4; ++c)
    for (int row = 0; row < 4; ++row) r[c][row] = static_cast<double>(static_cast<float>(m[c][row]));
  return r;
}

bool bitwiseEqual(const Mat4& a, const Mat4& b) { return std::memcmp(&a, &b, sizeof(Mat4)) == 0; }

// A small recording: frame i has a distinct pixel pattern, a timestamp at
// 30 Hz (not representable in binary), a ProbeToTracker pose whose entries are
// not float32 numbers and an affine ImageToReference with spacing.
std::vector<Frame> makeFrames(int n, int w, int h, PixelType type) {
  std::vector<Frame> frames;
  for (int i = 0; i < n; ++i) {
    Frame f;
    f.allocate(w, h, type);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const int v = (x * 7 + y * 13 + i * 31) ^ (x * y);
        const std::size_t k = static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x);
        if (type == PixelType::U8) {
          f.pixels[k] = static_cast<std::uint8_t>(v);
        } else {
          const auto u = static_cast<std::uint16_t>(v * 257 + i);
          f.pixels[2 * k] = static_cast<std::uint8_t>(u & 0xff);
          f.pixels[2 * k + 1] = static_cast<std::uint8_t>(u >> 8);
        }
      }
    f.index = static_cast<std::uint64_t>(i);
    f.timestamp = 12.0 + i / 30.0;
    const Mat4 pose = translation({10.1 + 0.37 * i, -3.3, 41.7}) * rotationAxisAngle({0.3, 1.0, 0.2}, 0.01 * i + 0.1);
    f.setTransform("ProbeToTracker", pose);
    const Mat4 image = translation({-20.3, 5.1 + 0.1 * i, 80.9}) * rotationAxisAngle({1.0, 0.1, 0.0}, 0.2 + 0.003 * i) *
                       scaling({0.21, 0.33, 1.0});
    f.setTransform("ImageToReference", image);
    f.customFields = {{"SpeedOfSound", std::to_string(1540 + i)}};
    frames.push_back(std::move(f));
  }
  return frames;
}

// pp5echo-igtl-server as a child process; always killed and reaped.
class Server {
public:
  Server(const TempDir& dir, std::vector<std::string> args) : portFile_(dir / "port"), log_(dir / "server.log") {
    std::filesystem::remove(portFile_);
    args.insert(args.begin(), PP5_IGTL_SERVER);
    for (const char* a : {"--port", "0", "--port-file"}) args.push_back(a);
    args.push_back(portFile_);
    args.push_back("--accept-timeout-s");
    args.push_back("20");
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 2, log_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int rc = posix_spawn(&pid_, argv[0], &fa, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) throw std::runtime_error(std::string("cannot start the server: ") + std::strerror(rc));
    // The server writes the port file (atomically) once it listens.
    const auto t0 = Clock::now();
    while (!std::filesystem::exists(portFile_)) {
      if (secondsSince(t0) > 20 || exitedEarly()) {
        const std::string why = "the server did not start:\n" + log();
        killChild();  // the destructor does not run for a throwing constructor
        throw std::runtime_error(why);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    std::ifstream in(portFile_);
    in >> port_;
  }
  ~Server() { killChild(); }
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  int port() const { return port_; }
  Endpoint endpoint() const { return {"127.0.0.1", port_}; }
  std::string log() const {
    std::ifstream in(log_);
    return std::string(std::istreambuf_iterator<char>(in), {});
  }
  // The exit status (-1 when it had to be killed after `timeoutS`).
  int wait(double timeoutS = 20) {
    const auto t0 = Clock::now();
    while (pid_ > 0) {
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      }
      if (secondsSince(t0) > timeoutS) {
        killChild();
        return -1;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return -1;
  }

private:
  void killChild() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
      pid_ = -1;
    }
  }
  bool exitedEarly() {
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      return true;
    }
    return false;
  }

  std::string portFile_, log_;
  pid_t pid_ = -1;
  int port_ = 0;
};

struct Received {
  std::vector<Frame> frames;
  ClientStats stats;
};

Received receive(ClientOptions opt, std::uint64_t stopAfter = 0) {
  Client client(std::move(opt));
  std::atomic<bool> stop{false};
  Received r;
  client.run(
      [&](Frame&& f) {
        r.frames.push_back(std::move(f));
        if (stopAfter && r.frames.size() >= stopAfter) stop = true;
      },
      stop);
  r.stats = client.stats();
  return r;
}

ClientOptions options(const Server& s) {
  ClientOptions o;
  o.endpoint = s.endpoint();
  o.connectTimeoutS = 10;
  o.reconnect = false;
  return o;
}

void expectSamePixels(const Frame& got, const Frame& want) {
  ASSERT_EQ(got.width, want.width);
  ASSERT_EQ(got.height, want.height);
  ASSERT_EQ(got.pixelType, want.pixelType);
  EXPECT_TRUE(got.pixels == want.pixels) << "frame " << got.index;
}

// ---------------------------------------------------------------------------

TEST(IgtlUrl, Good) {
  Endpoint e = parseIgtlUrl("igtl://localhost:18945");
  EXPECT_EQ(e.host, "localhost");
  EXPECT_EQ(e.port, 18945);
  e = parseIgtlUrl("igtl://10.0.0.2");
  EXPECT_EQ(e.host, "10.0.0.2");
  EXPECT_EQ(e.port, 18944);
  e = parseIgtlUrl("igtl://scanner.local:1/");
  EXPECT_EQ(e.host, "scanner.local");
  EXPECT_EQ(e.port, 1);
  e = parseIgtlUrl("igtl://[::1]:5000");
  EXPECT_EQ(e.host, "::1");
  EXPECT_EQ(e.port, 5000);
  EXPECT_EQ(toString(e), "[::1]:5000");
}

TEST(IgtlUrl, Bad) {
  for (const char* url : {"", "localhost:18944", "http://host:1", "igtl://", "igtl://:5", "igtl://h:", "igtl://h:abc",
                          "igtl://h:0", "igtl://h:65536", "igtl://h:1:2", "igtl://h/x", "igtl://[::1", "igtl://[::1]x",
                          "IGTL://h:1", "igtl://h:-1", "igtl://h:123456"}) {
    try {
      parseIgtlUrl(url);
      ADD_FAILURE() << "accepted " << url;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(std::string("'") + url + "'"), std::string::npos) << e.what();
    }
  }
}

// 100 frames arrive with their pixels, timestamps and float-rounded poses; the
// server's record of what it sent equals what arrived.
TEST(IgtlClient, StreamsAllFramesExactly) {
  TempDir dir;
  const auto frames = makeFrames(100, 64, 48, PixelType::U8);
  writeAllFrames(dir / "seq.igs.mha", frames);
  Server server(dir, {dir / "seq.igs.mha", "--fps", "0", "--frames", "100", "--write-sent", dir / "sent.igs.mha"});
  const Received r = receive(options(server));
  ASSERT_EQ(server.wait(), 0) << server.log();

  ASSERT_EQ(r.frames.size(), 100u) << server.log();
  int roundedDiffers = 0;
  for (std::size_t i = 0; i < r.frames.size(); ++i) {
    const Frame& got = r.frames[i];
    EXPECT_EQ(got.index, i);
    expectSamePixels(got, frames[i]);
    EXPECT_NEAR(got.timestamp, frames[i].timestamp, 1e-6);
    EXPECT_TRUE(got.imageValid);
    ASSERT_EQ(got.transforms.size(), 1u);
    const FrameTransform& t = got.transforms[0];
    EXPECT_EQ(t.name, "ProbeToTracker");
    EXPECT_TRUE(t.valid);
    const Mat4 want = floatRounded(frames[i].findTransform("ProbeToTracker")->matrix);
    EXPECT_TRUE(bitwiseEqual(t.matrix, want)) << "frame " << i << ": " << formatRowMajor(t.matrix) << " vs "
                                               << formatRowMajor(want);
    roundedDiffers += !bitwiseEqual(want, frames[i].findTransform("ProbeToTracker")->matrix);
  }
  EXPECT_GT(roundedDiffers, 0);  // the rounding is really being checked
  EXPECT_EQ(r.stats.images, 100u);
  EXPECT_EQ(r.stats.transforms, 100u);
  EXPECT_EQ(r.stats.paired, 100u);
  EXPECT_EQ(r.stats.imagesWithoutPose, 0u);
  EXPECT_EQ(r.stats.disconnects, 1u);  // the server hangs up after the last frame
  EXPECT_EQ(r.stats.reconnects, 0u);
  EXPECT_GT(r.stats.bytes, 100u * 64u * 48u);

  const auto sent = readAllFrames(dir / "sent.igs.mha");
  ASSERT_EQ(sent.size(), r.frames.size());
  for (std::size_t i = 0; i < sent.size(); ++i) {
    const Frame& got = r.frames[i];
    EXPECT_EQ(sent[i].index, got.index);
    expectSamePixels(sent[i], got);
    EXPECT_EQ(sent[i].timestamp, got.timestamp) << "frame " << i;
    ASSERT_EQ(sent[i].transforms.size(), got.transforms.size());
    EXPECT_EQ(sent[i].transforms[0].name, got.transforms[0].name);
    EXPECT_TRUE(bitwiseEqual(sent[i].transforms[0].matrix, got.transforms[0].matrix)) << "frame " << i;
    EXPECT_EQ(sent[i].customFields, frames[i].customFields);
  }
}

// uint16 pixels sent big-endian arrive as the Frame's little-endian.
// The local address of the TCP socket listening on `port` (from
// /proc/net/tcp, hex as the kernel writes it: 0100007F is 127.0.0.1), "" if none.
std::string listeningAddress(int port) {
  std::ifstream in("/proc/net/tcp");
  std::string line;
  std::getline(in, line);  // the column names
  char want[8];
  std::snprintf(want, sizeof want, "%04X", port);
  while (std::getline(in, line)) {
    std::istringstream ss(line);
    std::string slot, local, remote, state;
    ss >> slot >> local >> remote >> state;
    if (state == "0A" && local.size() == 13 && local.substr(9) == want) return local.substr(0, 8);
  }
  return "";
}

// pp5echo-igtl-server listens on this machine only unless --bind says
// otherwise (it listened on every interface, issue 20 item 7).
TEST(IgtlServer, ListensOnLoopbackUnlessToldOtherwise) {
  TempDir dir;
  writeAllFrames(dir / "seq.igs.mha", makeFrames(3, 16, 8, PixelType::U8));
  {
    Server server(dir, {dir / "seq.igs.mha", "--fps", "0"});
    EXPECT_EQ(listeningAddress(server.port()), "0100007F");
  }
  {
    Server server(dir, {dir / "seq.igs.mha", "--fps", "0", "--bind", "0.0.0.0"});
    EXPECT_EQ(listeningAddress(server.port()), "00000000");
  }
  EXPECT_THROW(Server(dir, {dir / "seq.igs.mha", "--bind", "999.0.0.1"}), std::runtime_error);
}

// One IMAGE a frame cannot hold (RGB) among good ones: skipped and counted,
// and the frames before and after it arrive (it used to end the scan).
TEST(IgtlClient, AnImageItCannotUseIsSkippedAndCounted) {
  auto packed = [](int components) {
    auto img = ::igtl::ImageMessage::New();
    img->SetDeviceName("Image");
    img->SetDimensions(8, 6, 1);
    img->SetScalarType(::igtl::ImageMessage::TYPE_UINT8);
    img->SetNumComponents(components);
    img->AllocateScalars();
    std::memset(img->GetScalarPointer(), 7, static_cast<std::size_t>(img->GetImageSize()));
    img->Pack();
    const auto* p = static_cast<const std::uint8_t*>(img->GetPackPointer());
    return std::vector<std::uint8_t>(p, p + img->GetPackSize());
  };
  std::vector<std::uint8_t> stream;
  for (int comps : {1, 3, 1}) {
    const auto m = packed(comps);
    stream.insert(stream.end(), m.begin(), m.end());
  }
  int fds[2];
  ASSERT_EQ(socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, fds), 0);
  ASSERT_EQ(::write(fds[1], stream.data(), stream.size()), static_cast<ssize_t>(stream.size()));
  ::close(fds[1]);
  Client client(ClientOptions{});
  std::vector<Frame> got;
  client.decode(fds[0], [&](Frame&& f) { got.push_back(std::move(f)); });
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[0].width, 8);
  EXPECT_EQ(got[1].pixels, got[0].pixels);
  const ClientStats st = client.stats();
  EXPECT_EQ(st.images, 2u);
  EXPECT_EQ(st.rejected, 1u);
  EXPECT_EQ(st.skipped, 1u);
}

TEST(IgtlClient, Uint16BigEndian) {
  TempDir dir;
  const auto frames = makeFrames(10, 40, 30, PixelType::U16);
  writeAllFrames(dir / "seq.igs.mha", frames);
  Server server(dir, {dir / "seq.igs.mha", "--fps", "0", "--big-endian"});
  const Received r = receive(options(server));
  ASSERT_EQ(r.frames.size(), 10u) << server.log();
  for (std::size_t i = 0; i < r.frames.size(); ++i) expectSamePixels(r.frames[i], frames[i]);
}

// Image_Reference carries the pose in the IMAGE: ImageToReference = matrix *
// diag(spacing), within float precision of the recording and bitwise equal to
// the server's record.
TEST(IgtlClient, ImageReferenceMatrix) {
  TempDir dir;
  const auto frames = makeFrames(20, 32, 24, PixelType::U16);
  writeAllFrames(dir / "seq.igs.mha", frames);
  Server server(dir, {dir / "seq.igs.mha", "--fps", "0", "--image-device", "Image_Reference", "--write-sent",
                      dir / "sent.igs.mha"});
  ClientOptions opt = options(server);
  opt.imageDevice = "Image_Reference";
  const Received r = receive(opt);
  ASSERT_EQ(server.wait(), 0) << server.log();
  ASSERT_EQ(r.frames.size(), 20u) << server.log();
  const auto sent = readAllFrames(dir / "sent.igs.mha");
  ASSERT_EQ(sent.size(), 20u);
  for (std::size_t i = 0; i < r.frames.size(); ++i) {
    const Frame& got = r.frames[i];
    expectSamePixels(got, frames[i]);
    ASSERT_EQ(got.transforms.size(), 2u);
    EXPECT_EQ(got.transforms[0].name, "ProbeToTracker");
    EXPECT_EQ(got.transforms[1].name, "ImageToReference");
    const Mat4& m = got.transforms[1].matrix;
    const Mat4& want = frames[i].findTransform("ImageToReference")->matrix;
    for (int c = 0; c < 4; ++c)
      for (int row = 0; row < 4; ++row)
        EXPECT_NEAR(m[c][row], want[c][row], 1e-5 * std::max(1.0, std::abs(want[c][row])))
            << "frame " << i << " row " << row << " col " << c;
    // Spacing is in the matrix: column lengths 0.21 and 0.33 mm per pixel.
    EXPECT_NEAR(glm::length(Vec3(m[0])), 0.21, 1e-6);
    EXPECT_NEAR(glm::length(Vec3(m[1])), 0.33, 1e-6);
    ASSERT_EQ(sent[i].transforms.size(), 2u);
    EXPECT_EQ(sent[i].transforms[1].name, "ImageToReference");
    EXPECT_TRUE(bitwiseEqual(sent[i].transforms[1].matrix, m)) << "frame " << i;
  }
  EXPECT_EQ(r.stats.imagesWithoutPose, 0u);
}

// A TRANSFORM pairs only within the tolerance; other IMAGE devices are skipped.
TEST(IgtlClient, PairingToleranceAndDeviceFilter) {
  TempDir dir;
  writeAllFrames(dir / "seq.igs.mha", makeFrames(12, 16, 8, PixelType::U8));
  {
    Server server(dir, {dir / "seq.igs.mha", "--fps", "0", "--transform-offset-s=-0.01"});
    const Received r = receive(options(server));
    ASSERT_EQ(r.frames.size(), 12u) << server.log();
    EXPECT_EQ(r.stats.paired, 12u);
    EXPECT_EQ(r.stats.imagesWithoutPose, 0u);
  }
  {
    Server server(dir, {dir / "seq.igs.mha", "--fps", "0", "--transform-offset-s=-0.05"});
    const Received r = receive(options(server));
    ASSERT_EQ(r.frames.size(), 12u) << server.log();
    EXPECT_EQ(r.stats.transforms, 12u);
    EXPECT_EQ(r.stats.paired, 0u);
    EXPECT_EQ(r.stats.imagesWithoutPose, 12u);
    for (const auto& f : r.frames) EXPECT_TRUE(f.transforms.empty());
  }
  {
    Server server(dir, {dir / "seq.igs.mha", "--fps", "0", "--transform", "NeedleToTracker"});
    // The file has no such transform: images only, each without a pose.
    const Received r = receive(options(server));
    ASSERT_EQ(r.frames.size(), 12u) << server.log();
    EXPECT_EQ(r.stats.imagesWithoutPose, 12u);
  }
  {
    Server server(dir, {dir / "seq.igs.mha", "--fps", "0"});
    ClientOptions opt = options(server);
    opt.imageDevice = "Image_Reference";
    const Received r = receive(opt);
    EXPECT_TRUE(r.frames.empty());
    EXPECT_EQ(r.stats.skipped, 12u);  // the IMAGEs of device "Image"
    EXPECT_EQ(r.stats.transforms, 12u);
  }
}

// The server hangs up after 30 of 100 frames; without reconnection run()
// returns with those 30.
TEST(IgtlClient, ServerVanishesNoReconnect) {
  TempDir dir;
  const auto frames = makeFrames(100, 64, 48, PixelType::U8);
  writeAllFrames(dir / "seq.igs.mha", frames);
  Server server(dir, {dir / "seq.igs.mha", "--fps", "200", "--vanish-after", "30", "--write-sent", dir / "sent.igs.mha"});
  const auto t0 = Clock::now();
  const Received r = receive(options(server));
  EXPECT_LT(secondsSince(t0), 5.0);
  ASSERT_EQ(server.wait(), 0) << server.log();
  ASSERT_EQ(r.frames.size(), 30u) << server.log();
  for (std::size_t i = 0; i < r.frames.size(); ++i) expectSamePixels(r.frames[i], frames[i]);
  EXPECT_EQ(r.stats.disconnects, 1u);
  EXPECT_EQ(r.stats.reconnects, 0u);
  EXPECT_EQ(readAllFrames(dir / "sent.igs.mha").size(), 30u);
}

// With reconnection on, a server that does not come back ends the stream
// after reconnectTimeoutS, keeping what arrived.
TEST(IgtlClient, ServerVanishesReconnectTimesOut) {
  TempDir dir;
  writeAllFrames(dir / "seq.igs.mha", makeFrames(40, 16, 8, PixelType::U8));
  Server server(dir, {dir / "seq.igs.mha", "--fps", "0", "--vanish-after", "30"});
  ClientOptions opt = options(server);
  opt.reconnect = true;
  opt.reconnectTimeoutS = 0.5;
  const auto t0 = Clock::now();
  const Received r = receive(opt);
  const double took = secondsSince(t0);
  EXPECT_GE(took, 0.5);
  EXPECT_LT(took, 5.0);
  EXPECT_EQ(r.frames.size(), 30u);
  EXPECT_EQ(r.stats.disconnects, 1u);
  EXPECT_EQ(r.stats.reconnects, 0u);
}

// The server goes away after 30 frames and comes back 0.5 s later: all 100
// frames arrive, in order, after one reconnection.
TEST(IgtlClient, ServerReappears) {
  TempDir dir;
  const auto frames = makeFrames(100, 64, 48, PixelType::U8);
  writeAllFrames(dir / "seq.igs.mha", frames);
  Server server(dir, {dir / "seq.igs.mha", "--fps", "200", "--vanish-after", "30", "--reappear-after-s", "0.5",
                      "--write-sent", dir / "sent.igs.mha"});
  ClientOptions opt = options(server);
  opt.reconnect = true;
  opt.reconnectTimeoutS = 10;
  const Received r = receive(opt, 100);
  ASSERT_EQ(r.frames.size(), 100u) << server.log();
  for (std::size_t i = 0; i < r.frames.size(); ++i) {
    EXPECT_EQ(r.frames[i].index, i);
    expectSamePixels(r.frames[i], frames[i]);
    EXPECT_NEAR(r.frames[i].timestamp, frames[i].timestamp, 1e-6);
    ASSERT_EQ(r.frames[i].transforms.size(), 1u);
  }
  EXPECT_EQ(r.stats.disconnects, 1u);
  EXPECT_EQ(r.stats.reconnects, 1u);
  EXPECT_EQ(server.wait(), 0) << server.log();
  EXPECT_EQ(readAllFrames(dir / "sent.igs.mha").size(), 100u);
}

// A port nobody listens on (bound, never listening, so no one else takes it).
struct DeadPort {
  DeadPort() {
    fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = 0;
    if (::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) throw std::runtime_error("bind");
    socklen_t len = sizeof a;
    ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
    port = ntohs(a.sin_port);
  }
  ~DeadPort() { ::close(fd); }
  // A client for this port that gives up connecting after `timeoutS`.
  ClientOptions options(double timeoutS) const {
    ClientOptions opt;
    opt.endpoint = {"127.0.0.1", port};
    opt.connectTimeoutS = timeoutS;
    return opt;
  }
  int fd = -1;
  int port = 0;
};

TEST(IgtlClient, ConnectionRefusedIsAClearError) {
  DeadPort dead;
  Client client(dead.options(1.0));
  std::atomic<bool> stop{false};
  const auto t0 = Clock::now();
  try {
    client.run([](Frame&&) {}, stop);
    FAIL() << "connected to a dead port";
  } catch (const DeviceError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("127.0.0.1:" + std::to_string(dead.port)), std::string::npos) << msg;
    EXPECT_NE(msg.find("cannot connect"), std::string::npos) << msg;
  }
  const double took = secondsSince(t0);
  EXPECT_GE(took, 0.9);
  EXPECT_LT(took, 2.5);

}

// `stop` ends run() quickly, both while streaming and while connecting.
TEST(IgtlClient, StopIsHonouredQuickly) {
  TempDir dir;
  writeAllFrames(dir / "seq.igs.mha", makeFrames(100, 16, 8, PixelType::U8));
  Server server(dir, {dir / "seq.igs.mha", "--fps", "4"});
  Client client(options(server));
  std::atomic<bool> stop{false};
  std::atomic<int> got{0};
  std::atomic<bool> returned{false};
  std::thread t([&] {
    client.run([&](Frame&&) { ++got; }, stop);
    returned = true;
  });
  while (got == 0 && !returned) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));  // now waiting for the next frame
  EXPECT_FALSE(returned.load());
  const auto t0 = Clock::now();
  stop = true;
  while (!returned && secondsSince(t0) < 5) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  const double took = secondsSince(t0);
  t.join();
  EXPECT_LT(took, 0.25);
  EXPECT_GE(got.load(), 1);
  EXPECT_LT(got.load(), 5);

  DeadPort dead;
  Client connecting(dead.options(30.0));
  std::atomic<bool> stop2{false};
  std::thread stopper([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    stop2 = true;
  });
  const auto t1 = Clock::now();
  EXPECT_NO_THROW(connecting.run([](Frame&&) {}, stop2));
  stopper.join();
  EXPECT_LT(secondsSince(t1), 0.6);
}

}  // namespace
}  // namespace pp5::igtl
