// pp5echo-igtl-server: streams a PLUS sequence over OpenIGTLink the way a PLUS
// server does (each frame's TRANSFORMs, then its IMAGE), to one client. It is
// the counterpart of pp5::igtl::Client for tests and demos, and can drop the
// connection mid-stream (and come back) to exercise the client's reconnection.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "core/error.hpp"
#include "formats/sequence_io.hpp"
#include "igtl/igtl_client.hpp"
#include "igtl/igtl_server.hpp"
#include "igtl/igtl_codec.hpp"
#include "igtl/igtl_wire.hpp"

namespace {

using namespace pp5;
using Clock = std::chrono::steady_clock;

struct Options {
  std::string sequence;
  int port = pp5::igtl::kDefaultPort;
  std::string bind = "127.0.0.1";  // this machine only, unless asked
  double fps = 30.0;
  std::uint64_t frames = 0;  // 0: all
  std::vector<std::string> transforms{"ProbeToTracker"};
  std::string imageDevice = "Image";
  long long vanishAfter = -1;
  double reappearAfterS = -1.0;
  std::string writeSent;
  std::string portFile;
  bool bigEndian = false;
  double acceptTimeoutS = 60.0;
  double transformOffsetS = 0.0;
};

template <typename... Args>
void event(fmt::format_string<Args...> f, Args&&... args) {
  fmt::print(stderr, "pp5echo-igtl-server: {}\n", fmt::format(f, std::forward<Args>(args)...));
  std::fflush(stderr);
}

// Written under a temporary name and renamed, so a test polling for the file
// never reads it half-written.
void writePortFile(const std::string& path, int port) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::trunc);
    out << port << "\n";
    if (!out) throw InputError(fmt::format("{}: cannot write the port file", tmp));
  }
  std::filesystem::rename(tmp, path);
}

// Plain POSIX sockets rather than igtl::ServerSocket: that one sets no
// SO_REUSEADDR, so after --vanish-after it could not listen again on the port
// of the connection it had just closed (the port sits in TIME_WAIT).
class Listener {
public:
  ~Listener() { close(); }
  void open(const std::string& address, int port) {
    in_addr probe{};
    if (::inet_pton(AF_INET, address.c_str(), &probe) != 1)
      throw InputError(fmt::format("--bind {}: give an IPv4 address (127.0.0.1 for this machine, 0.0.0.0 for every "
                                   "interface)",
                                   address));
    fd_ = pp5::igtl::listenTcp(address, port, 1, port_, "pp5echo-igtl-server");
  }
  int port() const { return port_; }
  int accept(double timeoutS) {
    const auto deadline =
        Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(timeoutS));
    while (Clock::now() < deadline) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 200) <= 0) continue;
      const int c = ::accept4(fd_, nullptr, nullptr, SOCK_CLOEXEC);
      if (c >= 0) {
        const int one = 1;  // each message as soon as it is written, as a live source would
        ::setsockopt(c, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        return c;
      }
    }
    throw InputError(fmt::format("port {}: no client connected within {} s", port_, timeoutS));
  }
  void close() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

private:
  int fd_ = -1;
  int port_ = 0;
};

void sendMessage(int fd, const std::string& m, std::uint64_t frame) {
  const char* p = m.data();
  std::size_t left = m.size();
  while (left > 0) {
    const ssize_t n = ::send(fd, p, left, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw InputError(fmt::format("frame {}: the client went away ({})", frame, std::strerror(errno)));
    p += n;
    left -= static_cast<std::size_t>(n);
  }
}

// Decodes a packed IMAGE as a receiver does (the client's own decoding), so
// that the recording holds exactly what a client got.
void receivedCopy(const std::string& packed, Frame& f, Mat4& pixelToFrame) {
  namespace codec = pp5::igtl::codec;
  const codec::Header h = codec::readHeader(reinterpret_cast<const std::uint8_t*>(packed.data()));
  const std::string content = codec::readBody(h.version, packed.substr(codec::kHeaderBytes)).content;
  const codec::Image im = codec::readImage(content);
  pp5::igtl::wire::imageToFrame(im, content, h.device, h.time, f);
  pixelToFrame = pp5::igtl::wire::imagePixelToFrame(im);
}

int serve(const Options& o) {
  for (const auto& name : o.transforms)
    if (name.empty() || name.size() > pp5::igtl::wire::kMaxDeviceName)
      throw InputError(fmt::format("--transform '{}': device names are 1 to {} characters", name,
                                   pp5::igtl::wire::kMaxDeviceName));
  if (o.imageDevice.empty() || o.imageDevice.size() > pp5::igtl::wire::kMaxDeviceName)
    throw InputError(fmt::format("--image-device '{}': device names are 1 to {} characters", o.imageDevice,
                                 pp5::igtl::wire::kMaxDeviceName));
  const std::string imageFrame = pp5::igtl::wire::imageFrameName(o.imageDevice);
  const std::string imageTransform = imageFrame.empty() ? "" : "ImageTo" + imageFrame;

  auto reader = SequenceReader::open(o.sequence);
  const SequenceInfo& info = reader->info();
  std::uint64_t total = info.frameCount;
  if (o.frames > 0 && o.frames < total) total = o.frames;
  event("{}: {} frames of {}x{} ({}), sending {}", o.sequence, info.frameCount, info.width, info.height,
        info.pixelType == PixelType::U8 ? "uint8" : "uint16", total);

  std::unique_ptr<SequenceWriter> sentWriter;
  if (!o.writeSent.empty()) {
    SequenceWriteOptions wo;
    wo.fields = info.fields;
    sentWriter = SequenceWriter::create(o.writeSent, wo);
  }

  Listener listener;
  listener.open(o.bind, o.port);
  const int port = listener.port();
  if (!o.portFile.empty()) writePortFile(o.portFile, port);
  event("listening on port {}", port);
  int client = listener.accept(o.acceptTimeoutS);
  event("client connected");

  std::set<std::string> missingReported;
  Frame f;
  std::uint64_t k = 0;
  bool vanished = false;
  auto paceStart = Clock::now();
  std::uint64_t paceFirst = 0;
  // A client that goes away ends the stream with an error; the record of
  // what was sent keeps every frame sent before it.
  struct CloseRecordOnError {
    std::unique_ptr<SequenceWriter>& w;
    ~CloseRecordOnError() {
      if (w && std::uncaught_exceptions() > 0) try {
          w->close();
        } catch (const std::exception&) {
        }
    }
  } closeRecordOnError{sentWriter};
  while (k < total && reader->next(f)) {
    if (o.vanishAfter >= 0 && k == static_cast<std::uint64_t>(o.vanishAfter) && !vanished) {
      vanished = true;
      // The listener first: closed second, it could still take the client's
      // immediate reconnection into its backlog and then reset it.
      listener.close();
      ::close(client);
      client = -1;
      event("vanished after {} frames", k);
      if (o.reappearAfterS < 0) break;
      std::this_thread::sleep_for(std::chrono::duration<double>(o.reappearAfterS));
      listener.open(o.bind, port);
      event("listening on port {} again", port);
      client = listener.accept(o.acceptTimeoutS);
      event("client connected again");
      paceStart = Clock::now();
      paceFirst = k;
    }
    if (o.fps > 0) std::this_thread::sleep_until(paceStart + std::chrono::duration_cast<Clock::duration>(
                                                               std::chrono::duration<double>((k - paceFirst) / o.fps)));

    const auto stamp = pp5::igtl::wire::encodeTime(f.timestamp);
    Frame sent;
    sent.index = k;
    sent.customFields = f.customFields;

    for (const auto& name : o.transforms) {
      const FrameTransform* t = f.findTransform(name);
      if (!t || !t->valid) {
        if (missingReported.insert(name).second)
          event("frame {}: no valid {} transform; it is not sent for such frames", k, name);
        continue;
      }
      const auto tstamp = o.transformOffsetS == 0.0 ? stamp : pp5::igtl::wire::encodeTime(f.timestamp + o.transformOffsetS);
      const std::string msg = pp5::igtl::wire::packTransform(name, t->matrix, pp5::igtl::wire::decodeTime(tstamp));
      sendMessage(client, msg, k);
      const pp5::igtl::codec::Body got = pp5::igtl::codec::readBody(1, msg.substr(pp5::igtl::codec::kHeaderBytes));
      sent.transforms.push_back({pp5::igtl::wire::transformName(name), pp5::igtl::wire::transformOf(got.content), true});
    }

    Mat4 pixelToFrame(1.0);
    if (!imageFrame.empty()) {
      const FrameTransform* t = f.findTransform(imageTransform);
      if (!t || !t->valid)
        throw InputError(fmt::format("{}: frame {} has no valid {} transform, which --image-device {} sends",
                                     o.sequence, k, imageTransform, o.imageDevice));
      pixelToFrame = t->matrix;
    }
    const std::string img = pp5::igtl::wire::packFrame(o.imageDevice, f, pixelToFrame, o.bigEndian, stamp);
    sendMessage(client, img, k);

    if (sentWriter) {
      Mat4 received(1.0);
      receivedCopy(img, sent, received);
      if (!imageFrame.empty()) sent.transforms.push_back({imageTransform, received, true});
      sentWriter->write(sent);
    }
    event("frame {} sent (t = {:.6f} s)", k, f.timestamp);
    ++k;
  }
  // The listener first, as on --vanish-after: closed second, it could still
  // take the client's immediate reconnection attempt and then reset it.
  listener.close();
  if (client >= 0) ::close(client);
  if (sentWriter) std::exchange(sentWriter, nullptr)->close();
  event("done: {} frames sent", k);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  CLI::App app{"pp5echo-igtl-server: streams a PLUS sequence over OpenIGTLink to one client (tests and demos)"};
  app.add_option("sequence", o.sequence, "PLUS sequence (.igs.mha, .seq.nrrd, ...)")->required();
  app.add_option("--port", o.port, "TCP port; 0 picks a free one (see --port-file)")->required()->check(CLI::Range(0, 65535));
  app.add_option("--bind", o.bind, "Address to listen on (default 127.0.0.1, this machine only; 0.0.0.0 for every "
                                   "interface)");
  app.add_option("--fps", o.fps, "frames per second; 0 sends as fast as possible")->check(CLI::NonNegativeNumber);
  app.add_option("--frames", o.frames, "send at most this many frames (0: all)");
  app.add_option("--transform", o.transforms, "transform sent as a TRANSFORM before each IMAGE (repeatable)")
      ->take_all();
  app.add_option("--image-device", o.imageDevice,
                 "IMAGE device name; Image_<Frame> sends the frame's ImageTo<Frame> transform as the image matrix");
  app.add_option("--vanish-after", o.vanishAfter, "close the connection after this many frames")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--reappear-after-s", o.reappearAfterS, "... then listen again after this many seconds and go on")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--write-sent", o.writeSent, "record the frames sent, as a client receives them, to this sequence");
  app.add_option("--port-file", o.portFile, "write the port listened on to this file");
  app.add_flag("--big-endian", o.bigEndian, "send uint16 pixels big-endian (tests the client's byte swap)");
  app.add_option("--accept-timeout-s", o.acceptTimeoutS, "give up when no client connects within this time")
      ->check(CLI::PositiveNumber);
  app.add_option("--transform-offset-s", o.transformOffsetS,
                 "stamp TRANSFORMs this much later than their IMAGE (tests the client's pairing tolerance)");
  CLI11_PARSE(app, argc, argv);
  // A client that hangs up must show as a failed send, not kill the process.
  std::signal(SIGPIPE, SIG_IGN);
  try {
    return serve(o);
  } catch (const std::exception& e) {
    event("error: {}", e.what());
    return 1;
  }
}
