// The OpenIGTLink server (src/igtl/igtl_server.hpp) against a peer we did not
// write: Debian's libopenigtlink 1.11 (igtl::ClientSocket and its message
// classes), on 127.0.0.1.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include <igtlCapabilityMessage.h>
#include <igtlClientSocket.h>
#include <igtlImageMessage.h>
#include <igtlMessageHeader.h>
#include <igtlStatusMessage.h>
#include <igtlStringMessage.h>

#include "core/error.hpp"
#include "formats/volume_io.hpp"
#include "igtl/igtl_server.hpp"

namespace {

using pp5::igtl::Server;
using pp5::igtl::ServerOptions;

ServerOptions anyPort() {
  ServerOptions o;
  o.port = 0;
  return o;
}

// A 3D uint8 IMAGE of 4x3x2 voxels whose values start at `first`.
std::string volumeMessage(const char* device, int first) {
  auto img = igtl::ImageMessage::New();
  img->SetDeviceName(device);
  img->SetDimensions(4, 3, 2);
  img->SetScalarType(igtl::ImageMessage::TYPE_UINT8);
  img->SetSpacing(0.5f, 0.5f, 0.5f);
  img->AllocateScalars();
  auto* p = static_cast<std::uint8_t*>(img->GetScalarPointer());
  for (int i = 0; i < 24; ++i) p[i] = static_cast<std::uint8_t>(first + i);
  img->Pack();
  return {static_cast<const char*>(img->GetPackPointer()), static_cast<std::size_t>(img->GetPackSize())};
}

struct Peer {
  igtl::ClientSocket::Pointer socket = igtl::ClientSocket::New();
  explicit Peer(int port) {
    EXPECT_EQ(socket->ConnectToServer("127.0.0.1", port), 0);
    socket->SetReceiveTimeout(10000);  // ms: a missing message fails the test instead of hanging it
  }
  // The next message's header, and its body unpacked into `body`.
  igtl::MessageHeader::Pointer next(igtl::MessageBase::Pointer& body) {
    auto h = igtl::MessageHeader::New();
    h->InitPack();
    EXPECT_EQ(socket->Receive(h->GetPackPointer(), h->GetPackSize()), h->GetPackSize());
    h->Unpack();
    const std::string type = h->GetDeviceType();
    if (type == "IMAGE") body = igtl::ImageMessage::New();
    else if (type == "STATUS") body = igtl::StatusMessage::New();
    else if (type == "CAPABILITY") body = igtl::CapabilityMessage::New();
    else body = igtl::MessageBase::New();
    body->SetMessageHeader(h);
    body->AllocatePack();
    if (body->GetPackBodySize() > 0) socket->Receive(body->GetPackBodyPointer(), body->GetPackBodySize());
    body->Unpack(1);
    return h;
  }
  void send(igtl::MessageBase& m) {
    m.Pack();
    socket->Send(m.GetPackPointer(), m.GetPackSize());
  }
};

bool waitFor(const std::function<bool()>& f) {
  for (int i = 0; i < 500 && !f(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  return f();
}

// A client gets the newest message of every kind when it connects and each
// new one as it is published; every client does.
TEST(IgtlServe, NewcomersGetTheNewestAndEveryoneGetsWhatFollows) {
  Server s(anyPort());
  s.publish("IMAGE", "Volume_Reference", volumeMessage("Volume_Reference", 1));
  s.publish("IMAGE", "Volume_Reference", volumeMessage("Volume_Reference", 7));  // replaces the first
  Peer a(s.port()), b(s.port());
  ASSERT_TRUE(waitFor([&] { return s.clients() == 2; }));
  for (Peer* p : {&a, &b}) {
    igtl::MessageBase::Pointer m;
    const auto h = p->next(m);
    ASSERT_STREQ(h->GetDeviceType(), "IMAGE");
    EXPECT_STREQ(h->GetDeviceName(), "Volume_Reference");
    auto* img = dynamic_cast<igtl::ImageMessage*>(m.GetPointer());
    int size[3];
    img->GetDimensions(size);
    EXPECT_EQ(size[0] * size[1] * size[2], 24);
    EXPECT_EQ(static_cast<std::uint8_t*>(img->GetScalarPointer())[0], 7);
  }
  s.publish("IMAGE", "Volume_Reference", volumeMessage("Volume_Reference", 50));
  for (Peer* p : {&a, &b}) {
    igtl::MessageBase::Pointer m;
    p->next(m);
    EXPECT_EQ(static_cast<std::uint8_t*>(dynamic_cast<igtl::ImageMessage*>(m.GetPointer())->GetScalarPointer())[0], 50);
  }
}

// GET_CAPABIL lists what it sends and answers; GET_STATUS is OK; GET_IMAGE
// answers with the newest image; a message it does not handle gets a STATUS
// error naming it; a message over the size limit ends that connection only.
TEST(IgtlServe, AnswersQueriesAndNamesWhatItDoesNotHandle) {
  Server s(anyPort());
  s.publish("IMAGE", "Volume_Reference", volumeMessage("Volume_Reference", 3));
  Peer p(s.port());
  igtl::MessageBase::Pointer m;
  ASSERT_STREQ(p.next(m)->GetDeviceType(), "IMAGE");  // on connect

  auto getCap = igtl::GetCapabilityMessage::New();
  p.send(*getCap);
  ASSERT_STREQ(p.next(m)->GetDeviceType(), "CAPABILITY");
  const auto types = dynamic_cast<igtl::CapabilityMessage*>(m.GetPointer())->GetTypes();
  for (const char* t : {"IMAGE", "STATUS", "GET_IMAGE", "GET_STATUS", "GET_CAPABIL"})
    EXPECT_NE(std::find(types.begin(), types.end(), t), types.end()) << t;

  auto getStatus = igtl::GetStatusMessage::New();
  p.send(*getStatus);
  ASSERT_STREQ(p.next(m)->GetDeviceType(), "STATUS");
  EXPECT_EQ(dynamic_cast<igtl::StatusMessage*>(m.GetPointer())->GetCode(), igtl::StatusMessage::STATUS_OK);

  auto getImage = igtl::GetImageMessage::New();
  getImage->SetDeviceName("Volume_Reference");
  p.send(*getImage);
  ASSERT_STREQ(p.next(m)->GetDeviceType(), "IMAGE");
  EXPECT_EQ(static_cast<std::uint8_t*>(dynamic_cast<igtl::ImageMessage*>(m.GetPointer())->GetScalarPointer())[0], 3);
  getImage->SetDeviceName("Nothing");
  p.send(*getImage);
  ASSERT_STREQ(p.next(m)->GetDeviceType(), "STATUS");
  EXPECT_EQ(dynamic_cast<igtl::StatusMessage*>(m.GetPointer())->GetCode(), igtl::StatusMessage::STATUS_NOT_FOUND);

  auto text = igtl::StringMessage::New();
  text->SetDeviceName("Hello");
  text->SetString("hello");
  p.send(*text);
  ASSERT_STREQ(p.next(m)->GetDeviceType(), "STATUS");
  auto* st = dynamic_cast<igtl::StatusMessage*>(m.GetPointer());
  EXPECT_EQ(st->GetCode(), igtl::StatusMessage::STATUS_UNKNOWN_INSTRUCTION);
  EXPECT_NE(std::string(st->GetStatusString()).find("STRING"), std::string::npos) << st->GetStatusString();

  // Too large: this connection ends, the server serves the next one.
  auto big = igtl::ImageMessage::New();
  big->SetDimensions(300, 300, 1);  // 90 kB of pixels
  big->SetScalarType(igtl::ImageMessage::TYPE_UINT8);
  big->AllocateScalars();
  std::memset(big->GetScalarPointer(), 0, 300 * 300);
  p.send(*big);
  Peer q(s.port());
  ASSERT_STREQ(q.next(m)->GetDeviceType(), "IMAGE");
  ASSERT_TRUE(waitFor([&] { return s.clients() == 1; }));
}

// publishImage places the image as OpenIGTLink defines an IMAGE's origin: the
// centre of the voxels, so that a receiver (Slicer) puts voxel 0 where it is.
TEST(IgtlServe, AnImagesOriginIsItsCentre) {
  Server s(anyPort());
  const std::uint8_t voxels[24] = {9};
  pp5::Mat4 m(1.0);
  for (int a = 0; a < 3; ++a) m[a][a] = 0.5;
  m[3] = pp5::Vec4(10.0, 20.0, 30.0, 1.0);
  s.publishImage("Volume_Reference", pp5::Index3(4, 3, 2), voxels, m, 12.5);
  Peer p(s.port());
  igtl::MessageBase::Pointer msg;
  ASSERT_STREQ(p.next(msg)->GetDeviceName(), "Volume_Reference");
  auto* img = dynamic_cast<igtl::ImageMessage*>(msg.GetPointer());
  float origin[3], spacing[3];
  img->GetOrigin(origin);
  img->GetSpacing(spacing);
  EXPECT_FLOAT_EQ(origin[0], 10.75f);  // 10 + (4 - 1) / 2 * 0.5
  EXPECT_FLOAT_EQ(origin[1], 20.5f);
  EXPECT_FLOAT_EQ(origin[2], 30.25f);
  EXPECT_FLOAT_EQ(spacing[0], 0.5f);
  EXPECT_EQ(static_cast<std::uint8_t*>(img->GetScalarPointer())[0], 9);
  igtlUint32 sec = 0, frac = 0;
  img->GetTimeStamp(&sec, &frac);
  EXPECT_EQ(sec, 12u);
}

// A free TCP port on 127.0.0.1 (bound, read, closed).
int freePort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  ::close(fd);
  return ntohs(a.sin_port);
}

// A one-process run with run.igtl_serve: a client of Debian's library gets
// the B-mode frames and the growing volume while the doll streams, and last
// the final volume, voxel for voxel the volume.mha the run writes (as uint8).
TEST(IgtlServe, ARunServesItsVolumeAndFramesToAClient) {
  const std::string dir = (std::filesystem::temp_directory_path() / ("pp5_igtl_serve_" + std::to_string(::getpid()))).string();
  std::filesystem::remove_all(dir);
  const int port = freePort();
  const std::string cmd = std::string(PP5_BINARY) + " run " + PP5_SOURCE_DIR + "/configs/doll.toml --serial -o " + dir +
                          " --igtl-serve 127.0.0.1:" + std::to_string(port) +
                          " --set sim.sweep.max_frames=40 --set run.orbit_frames=0 --set run.mpr=false > " + dir +
                          ".log 2>&1";
  std::thread runner([&] { EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd; });
  auto socket = igtl::ClientSocket::New();
  bool connected = false;
  for (int i = 0; i < 300 && !connected; ++i) {
    connected = socket->ConnectToServer("127.0.0.1", port) == 0;
    if (!connected) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_TRUE(connected);
  socket->SetReceiveTimeout(20000);
  int frames = 0, volumes = 0;
  std::vector<std::uint8_t> last;
  int lastDims[3] = {0, 0, 0};
  while (true) {
    auto h = igtl::MessageHeader::New();
    h->InitPack();
    if (socket->Receive(h->GetPackPointer(), h->GetPackSize()) != h->GetPackSize()) break;  // the run ended
    h->Unpack();
    auto img = igtl::ImageMessage::New();
    img->SetMessageHeader(h);
    img->AllocatePack();
    ASSERT_EQ(socket->Receive(img->GetPackBodyPointer(), img->GetPackBodySize()), img->GetPackBodySize());
    ASSERT_STREQ(h->GetDeviceType(), "IMAGE");
    img->Unpack(1);
    if (std::string(h->GetDeviceName()) == "Image_Reference") {
      ++frames;
    } else {
      ASSERT_STREQ(h->GetDeviceName(), "Volume_Reference");
      ++volumes;
      img->GetDimensions(lastDims);
      const auto* p = static_cast<const std::uint8_t*>(img->GetScalarPointer());
      last.assign(p, p + static_cast<std::size_t>(lastDims[0]) * lastDims[1] * lastDims[2]);
    }
  }
  runner.join();
  EXPECT_GE(frames, 1);
  EXPECT_GE(volumes, 2);  // the live one and the final one
  const pp5::Volume v = pp5::readVolume(dir + "/volume.mha").as(pp5::ScalarType::U8);
  ASSERT_EQ(lastDims[0], v.grid.dims.x);
  ASSERT_EQ(lastDims[1], v.grid.dims.y);
  ASSERT_EQ(lastDims[2], v.grid.dims.z);
  EXPECT_TRUE(last == v.bytes) << "the last volume sent is not the run's final volume";
  std::filesystem::remove_all(dir);
}

TEST(IgtlServe, ServeAddresses) {
  std::string a;
  int port = -1;
  pp5::igtl::parseServeAddress("18944", "run.igtl_serve", a, port);
  EXPECT_EQ(a, "127.0.0.1");
  EXPECT_EQ(port, 18944);
  pp5::igtl::parseServeAddress("0.0.0.0:0", "run.igtl_serve", a, port);
  EXPECT_EQ(a, "0.0.0.0");
  EXPECT_EQ(port, 0);
  for (const char* bad : {"", "x", "127.0.0.1:", ":18944", "18944x", "70000", "host.example:18944"})
    EXPECT_THROW(pp5::igtl::parseServeAddress(bad, "run.igtl_serve", a, port), pp5::InputError) << bad;
}

}  // namespace
