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
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <mutex>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <igtlCapabilityMessage.h>
#include <igtlClientSocket.h>
#include <igtlImageMessage.h>
#include <igtlMessageHeader.h>
#include <igtlStatusMessage.h>
#include <igtlStringMessage.h>
#include <igtlTransformMessage.h>
#include <igtl_util.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include <fmt/format.h>

#include "core/error.hpp"
#include "formats/sequence_io.hpp"
#include "formats/volume_io.hpp"
#include "igtl/igtl_client.hpp"
#include "igtl/igtl_server.hpp"
#include "igtl/igtl_wire.hpp"

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

// The live volume: whole to a newcomer, then a sub-volume IMAGE of only the
// bricks that changed (the whole volume's size and matrix, the box's offset,
// size and voxels), and whole again on GET_IMAGE.
TEST(IgtlServe, TheLiveVolumeGoesWholeThenAsTheBricksThatChanged) {
  Server s(anyPort());
  const pp5::Index3 dims(40, 20, 18);  // 3 x 2 x 2 bricks of 16, the last ones partial
  auto v = std::make_shared<std::vector<std::uint8_t>>(40 * 20 * 18, 1);
  pp5::Mat4 m(1.0);
  m[3] = pp5::Vec4(5.0, 6.0, 7.0, 1.0);
  s.publishVolume("Volume_Reference", dims, v, m, {}, 1.0);
  Peer p(s.port());
  igtl::MessageBase::Pointer msg;
  auto image = [&] {
    EXPECT_STREQ(p.next(msg)->GetDeviceName(), "Volume_Reference");
    return dynamic_cast<igtl::ImageMessage*>(msg.GetPointer());
  };
  int size[3], sub[3], off[3];
  image()->GetSubVolume(sub, off);
  EXPECT_EQ(sub[0] * sub[1] * sub[2], 40 * 20 * 18);
  // brick (2, 1, 1) changed: voxels x 32..39, y 16..19, z 16..17
  auto next = std::make_shared<std::vector<std::uint8_t>>(*v);
  (*next)[(17 * 20 + 19) * 40 + 39] = 200;
  std::vector<std::uint8_t> changed(12, 0);
  changed[(1 * 2 + 1) * 3 + 2] = 1;
  s.publishVolume("Volume_Reference", dims, next, m, changed, 2.0);
  auto* img = image();
  img->GetDimensions(size);
  img->GetSubVolume(sub, off);
  EXPECT_EQ(size[0], 40);
  EXPECT_EQ(size[2], 18);
  EXPECT_EQ(off[0], 32);
  EXPECT_EQ(off[1], 16);
  EXPECT_EQ(off[2], 16);
  EXPECT_EQ(sub[0], 8);
  EXPECT_EQ(sub[1], 4);
  EXPECT_EQ(sub[2], 2);
  const auto* px = static_cast<const std::uint8_t*>(img->GetScalarPointer());
  EXPECT_EQ(px[8 * 4 * 2 - 1], 200);
  EXPECT_EQ(px[0], 1);
  float origin[3];
  img->GetOrigin(origin);
  EXPECT_FLOAT_EQ(origin[0], 5.0f + 19.5f);  // the whole volume's centre
  auto get = igtl::GetImageMessage::New();
  get->SetDeviceName("Volume_Reference");
  p.send(*get);
  image()->GetSubVolume(sub, off);
  EXPECT_EQ(sub[0] * sub[1] * sub[2], 40 * 20 * 18);
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

// A raw TCP connection to the server, for bytes no library would send.
int rawConnect(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  EXPECT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
  timeval tv{10, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  return fd;
}

// Whether the server closed `fd` (reading what it sent before, up to the end).
bool closedByServer(int fd) {
  char buf[4096];
  while (true) {
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    if (n == 0) return true;
    if (n < 0) return false;  // timed out: still open
  }
}

std::string packedOf(igtl::MessageBase& m) {
  m.Pack();
  return {static_cast<const char*>(m.GetPackPointer()), static_cast<std::size_t>(m.GetPackSize())};
}

// A hostile client: garbage, a claimed 1 GiB body, a body size that wraps, a
// bad CRC. Each ends its connection with one clear line in the log; the
// server serves the next client.
TEST(IgtlServe, HostileInputEndsThatConnectionWithOneLogLine) {
  auto stream = std::make_shared<std::ostringstream>();
  auto sink = std::make_shared<spdlog::sinks::ostream_sink_mt>(*stream);
  spdlog::default_logger()->sinks().push_back(sink);
  Server s(anyPort());
  s.publish("IMAGE", "Volume_Reference", volumeMessage("Volume_Reference", 3));
  auto status = igtl::GetStatusMessage::New();
  const std::string good = packedOf(*status);
  auto withBodySize = [&](std::uint64_t size) {
    std::string m = good;
    for (int i = 0; i < 8; ++i) m[42 + i] = static_cast<char>(size >> (56 - 8 * i));
    return m;
  };
  auto text = igtl::StringMessage::New();
  text->SetDeviceName("CMD_1");
  text->SetString(R"(<Command Name="StartRecording"/>)");
  std::string badCrc = packedOf(*text);
  badCrc.back() ^= 0x20;  // the body changed after its CRC was taken
  const std::vector<std::pair<std::string, std::string>> cases = {
      {std::string(64, 'x') + "GET / HTTP/1.1\r\n\r\n", "not OpenIGTLink"},
      {withBodySize(std::uint64_t{1} << 30), "1073741824 bytes claimed"},
      {withBodySize(~std::uint64_t{0}), "18446744073709551615 bytes claimed"},
      {badCrc, "CRC"},
  };
  for (const auto& [bytes, said] : cases) {
    stream->str("");
    const int fd = rawConnect(s.port());
    ASSERT_EQ(::send(fd, bytes.data(), bytes.size(), MSG_NOSIGNAL), static_cast<ssize_t>(bytes.size()));
    EXPECT_TRUE(closedByServer(fd)) << said;
    ::close(fd);
    const std::string log = stream->str();
    EXPECT_EQ(std::count(log.begin(), log.end(), '\n'), 1) << log;
    EXPECT_NE(log.find(said), std::string::npos) << log;
    EXPECT_NE(log.find("connection closed"), std::string::npos) << log;
  }
  Peer next(s.port());
  igtl::MessageBase::Pointer m;
  EXPECT_STREQ(next.next(m)->GetDeviceName(), "Volume_Reference");
  spdlog::default_logger()->sinks().pop_back();
}

// Big-endian bytes, written out here from OpenIGTLink 3's layout (not with
// pp5echo's codec), for the messages Debian's 1.11 library cannot make.
void be(std::string& s, std::uint64_t v, int bytes) {
  for (int i = bytes - 1; i >= 0; --i) s.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}
std::uint64_t readBe(const std::string& s, std::size_t at, int bytes) {
  std::uint64_t v = 0;
  for (int i = 0; i < bytes; ++i) v = (v << 8) | static_cast<std::uint8_t>(s[at + static_cast<std::size_t>(i)]);
  return v;
}

// A version 2 message: header, extended header (12 bytes, no metadata), content.
std::string v2Message(const std::string& type, const std::string& device, std::uint32_t messageId, const std::string& content,
                      std::uint32_t seconds = 0) {
  std::string body;
  be(body, 12, 2);  // extended header size
  be(body, 0, 2);   // metadata header size
  be(body, 0, 4);   // metadata size
  be(body, messageId, 4);
  body += content;
  std::string m;
  be(m, 2, 2);
  std::string t = type, d = device;
  t.resize(12, '\0');
  d.resize(20, '\0');
  m += t + d;
  be(m, std::uint64_t{seconds} << 32, 8);  // timestamp
  be(m, body.size(), 8);
  be(m, crc64(reinterpret_cast<unsigned char*>(body.data()), body.size(), 0), 8);  // Debian's library's CRC
  return m + body;
}

// OpenIGTLink 3's COMMAND, as Slicer's Plus Remote sends it to a v3
// PlusServer: answered by an RTS_COMMAND (header version 2) with the same id
// and name, its metadata Status SUCCESS and the reply's text; an unknown one
// FAIL with an ErrorMessage.
TEST(IgtlServe, AnOpenIgtLink3CommandGetsAnRtsCommand) {
  Server s(anyPort());
  std::vector<pp5::igtl::Command> seen;
  std::mutex m;
  s.onCommand([&](const pp5::igtl::Command& c, pp5::igtl::CommandReply reply) {
    {
      const std::lock_guard lock(m);
      seen.push_back(c);
    }
    reply(c.name == "StartRecording", c.name == "StartRecording" ? "recording into " + c.attribute("OutputFilename") : "no");
  });
  const int fd = rawConnect(s.port());
  auto command = [&](std::uint32_t id, const std::string& name, const std::string& xml) {
    std::string c;
    be(c, id, 4);
    std::string n = name;
    n.resize(128, '\0');
    c += n;
    be(c, 3, 2);  // US-ASCII
    be(c, xml.size(), 4);
    c += xml;
    const std::string msg = v2Message("COMMAND", "Plus", id, c);
    ASSERT_EQ(::send(fd, msg.data(), msg.size(), MSG_NOSIGNAL), static_cast<ssize_t>(msg.size()));
  };
  // Reads one message; its type, version, and the content and metadata of its version 2 body.
  auto receive = [&](std::string& type, int& version, std::string& content, std::map<std::string, std::string>& meta) {
    std::string h(58, '\0');
    ASSERT_EQ(::recv(fd, h.data(), 58, MSG_WAITALL), 58);
    version = static_cast<int>(readBe(h, 0, 2));
    type = h.substr(2, 12).c_str();
    std::string body(readBe(h, 42, 8), '\0');
    ASSERT_EQ(::recv(fd, body.data(), body.size(), MSG_WAITALL), static_cast<ssize_t>(body.size()));
    EXPECT_EQ(readBe(h, 50, 8), crc64(reinterpret_cast<unsigned char*>(body.data()), body.size(), 0));
    meta.clear();
    if (version < 2) {
      content = body;
      return;
    }
    const std::size_t ext = readBe(body, 0, 2), metaHead = readBe(body, 2, 2), metaSize = readBe(body, 4, 4);
    content = body.substr(ext, body.size() - ext - metaHead - metaSize);
    std::size_t at = ext + content.size();
    const std::size_t n = readBe(body, at, 2);
    std::size_t data = at + metaHead;
    at += 2;
    for (std::size_t i = 0; i < n; ++i, at += 8) {
      const std::size_t k = readBe(body, at, 2), v = readBe(body, at + 4, 4);
      meta[body.substr(data, k)] = body.substr(data + k, v);
      data += k + v;
    }
  };
  command(41, "StartRecording", R"(<Command Name="StartRecording" OutputFilename="a.mha"/>)");
  std::string type, content;
  int version = 0;
  std::map<std::string, std::string> meta;
  receive(type, version, content, meta);
  EXPECT_EQ(type, "RTS_COMMAND");
  EXPECT_EQ(version, 2);
  ASSERT_GE(content.size(), 138u);
  EXPECT_EQ(readBe(content, 0, 4), 41u);
  EXPECT_STREQ(content.substr(4, 128).c_str(), "StartRecording");
  EXPECT_EQ(meta["Status"], "SUCCESS");
  EXPECT_NE(content.find("recording into a.mha"), std::string::npos) << content;
  command(42, "NoSuch", R"(<Command Name="NoSuch"/>)");
  receive(type, version, content, meta);
  EXPECT_EQ(readBe(content, 0, 4), 42u);
  EXPECT_EQ(meta["Status"], "FAIL");
  EXPECT_EQ(meta["ErrorMessage"], "no");
  ::close(fd);
  const std::lock_guard lock(m);
  ASSERT_EQ(seen.size(), 2u);
  EXPECT_TRUE(seen[0].v3);
  EXPECT_EQ(seen[0].attribute("OutputFilename"), "a.mha");
}

// An OpenIGTLink 3 server (a v3 PlusServer) sends version 2 bodies: the
// live source's client reads their content past the extended header, here
// a TRANSFORM and an IMAGE whose contents Debian's library packed.
TEST(IgtlServe, TheClientReadsVersion2Messages) {
  auto tr = igtl::TransformMessage::New();
  tr->SetDeviceName("ProbeToTracker");
  igtl::Matrix4x4 mat;
  igtl::IdentityMatrix(mat);
  mat[0][3] = 12.5f;
  tr->SetMatrix(mat);
  tr->SetTimeStamp(5, 0);
  auto img = igtl::ImageMessage::New();
  img->SetDeviceName("Image");
  img->SetDimensions(4, 2, 1);
  img->SetScalarType(igtl::ImageMessage::TYPE_UINT8);
  img->AllocateScalars();
  std::memset(img->GetScalarPointer(), 9, 8);
  img->SetTimeStamp(5, 0);
  auto contentOf = [](igtl::MessageBase& msg) { return packedOf(msg).substr(58); };
  const std::string stream = v2Message("TRANSFORM", "ProbeToTracker", 1, contentOf(*tr), 5) +
                             v2Message("IMAGE", "Image", 2, contentOf(*img), 5);
  int fds[2];
  ASSERT_EQ(::socketpair(AF_UNIX, SOCK_STREAM, 0, fds), 0);
  ASSERT_EQ(::send(fds[1], stream.data(), stream.size(), MSG_NOSIGNAL), static_cast<ssize_t>(stream.size()));
  ::close(fds[1]);
  pp5::igtl::ClientOptions o;
  pp5::igtl::Client client(o);
  std::vector<pp5::Frame> frames;
  client.decode(fds[0], [&](pp5::Frame&& f) { frames.push_back(std::move(f)); });
  ::close(fds[0]);
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0].width, 4);
  EXPECT_EQ(frames[0].pixels[7], 9);
  const pp5::FrameTransform* t = frames[0].findTransform("ProbeToTracker");
  ASSERT_NE(t, nullptr);
  EXPECT_DOUBLE_EQ(t->matrix[3][0], 12.5);
}

// A client reads an IMAGE's origin as OpenIGTLink defines it (the centre of
// the voxels), as PlusServer and Slicer send it: pixel 0 lies half the image
// before it.
TEST(IgtlServe, AClientReadsAnImagesOriginAsItsCentre) {
  auto img = igtl::ImageMessage::New();  // packed by Debian's library, read by pp5echo's codec
  img->SetDimensions(5, 3, 1);
  img->SetSpacing(0.5f, 0.25f, 1.0f);
  img->SetOrigin(10.0f, 20.0f, 30.0f);
  img->SetScalarType(igtl::ImageMessage::TYPE_UINT8);
  img->AllocateScalars();
  std::memset(img->GetScalarPointer(), 7, 15);
  const std::string bytes = packedOf(*img);
  namespace codec = pp5::igtl::codec;
  const codec::Header h = codec::readHeader(reinterpret_cast<const std::uint8_t*>(bytes.data()));
  const std::string content = codec::readBody(h.version, bytes.substr(codec::kHeaderBytes)).content;
  const codec::Image im = codec::readImage(content);
  const pp5::Mat4 m = pp5::igtl::wire::imagePixelToFrame(im);
  EXPECT_DOUBLE_EQ(m[3][0], 10.0 - 2 * 0.5);
  EXPECT_DOUBLE_EQ(m[3][1], 20.0 - 1 * 0.25);
  EXPECT_DOUBLE_EQ(m[3][2], 30.0);
  EXPECT_DOUBLE_EQ(m[0][0], 0.5);
  pp5::Frame f;
  pp5::igtl::wire::imageToFrame(im, content, h.device, h.time, f);
  EXPECT_EQ(f.width, 5);
  EXPECT_EQ(f.pixels[14], 7);
  // and back: the sender's matrix puts the centre there again
  codec::Image back;
  back.size[0] = 5, back.size[1] = 3;
  pp5::igtl::wire::setImageGeometry(back, m);
  EXPECT_FLOAT_EQ(back.matrix[9], 10.0f);
  EXPECT_FLOAT_EQ(back.matrix[10], 20.0f);
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

// A PlusServer command as Slicer's Plus Remote sends it: STRING CMD_<uid>.
void sendCommand(igtl::ClientSocket& socket, const std::string& uid, const std::string& xml) {
  auto m = igtl::StringMessage::New();
  m->SetDeviceName(("CMD_" + uid).c_str());
  m->SetEncoding(3);
  m->SetString(xml.c_str());
  m->Pack();
  socket.Send(m->GetPackPointer(), m->GetPackSize());
}

// What a client of Debian's library saw of a run with run.igtl_serve: the
// live volume assembled from the whole volume and its sub-volume updates,
// the counts of each kind, and the PlusServer commands' replies and volumes.
struct Seen {
  std::vector<std::uint8_t> volume;
  int dims[3] = {0, 0, 0};
  int wholeVolumes = 0, subVolumes = 0, frames = 0, framePoses = 0, views = 0;
  std::vector<std::string> replies;  // each ACK's text, in order
  struct Commanded {
    int dims[3];
    float spacing[3], origin[3];
  };
  std::vector<Commanded> commanded;  // the RecVol_Reference IMAGEs
  int againVolumes = 0;              // ReconstructVolume's ("Again")
  int probePoses = 0, rigidProbePoses = 0;  // ProbeToReference TRANSFORMs, and those that are rigid
  // The region of interest asked for: the middle half of the run's grid.
  int roiDims[3] = {0, 0, 0};
  double roiSpacing[3] = {0, 0, 0}, roiOrigin[3] = {0, 0, 0};  // voxel 0's centre
};

// One command of the workflow, sent once `framesBefore` B-mode frames came
// after the reply to the one before ("{ROI}" becomes the region's attributes).
struct Step {
  std::string xml;
  int framesBefore = 0;
};

// Runs the doll (paced, so that the commands land while it streams) with
// run.igtl_serve and a client that sends the Plus Remote workflow's commands
// one after the other, each after the reply to the one before.
// The commands are spaced by the frames the client receives (28 after the
// first whole volume); a loaded machine drops frames and sends the volume
// later, so the run has 90 frames, not the 60 after which a one-process run
// under a concurrent build had answered only 4 of its 9 commands (2026-12-04).
Seen runWithClient(const std::string& launcher, const std::string& dir, const std::vector<Step>& commands) {
  std::filesystem::remove_all(dir);
  const int port = freePort();
  const std::string cmd = launcher + std::string(PP5_BINARY) + " run " + PP5_SOURCE_DIR + "/configs/doll.toml" +
                          (launcher.empty() ? " --serial" : " --verify") + " -o " + dir + " --igtl-serve 127.0.0.1:" + std::to_string(port) +
                          " --set sim.sweep.max_frames=90 --set run.pace_fps=20 --set run.orbit_frames=0 "
                          "--set run.mpr=false > " + dir + ".log 2>&1";
  std::thread runner([&] { EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd << "\n(see " << dir << ".log)"; });
  Seen seen;
  auto socket = igtl::ClientSocket::New();
  bool connected = false;
  for (int i = 0; i < 600 && !connected; ++i) {
    connected = socket->ConnectToServer("127.0.0.1", port) == 0;
    if (!connected) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  EXPECT_TRUE(connected);
  if (!connected) {
    runner.join();
    return seen;
  }
  socket->SetReceiveTimeout(30000);
  std::size_t nextCommand = 0;
  int wait = -1;  // frames still to come before the next command (-1: waiting for a reply or the volume)
  auto sendNext = [&] {
    if (nextCommand >= commands.size()) return;
    std::string xml = commands[nextCommand].xml;
    const std::size_t at = xml.find("{ROI}");
    if (at != std::string::npos)
      xml.replace(at, 5, fmt::format("OutputSpacing=\"{} {} {}\" OutputOrigin=\"{} {} {}\" OutputExtent=\"0 {} 0 {} 0 {}\"",
                                     seen.roiSpacing[0], seen.roiSpacing[1], seen.roiSpacing[2], seen.roiOrigin[0],
                                     seen.roiOrigin[1], seen.roiOrigin[2], seen.roiDims[0] - 1, seen.roiDims[1] - 1,
                                     seen.roiDims[2] - 1));
    sendCommand(*socket, std::to_string(nextCommand + 1), xml);
    ++nextCommand;
    wait = -1;
  };
  auto schedule = [&] {
    if (nextCommand < commands.size()) wait = commands[nextCommand].framesBefore;
    if (wait == 0) sendNext();
  };
  while (true) {
    auto h = igtl::MessageHeader::New();
    h->InitPack();
    if (socket->Receive(h->GetPackPointer(), h->GetPackSize()) != h->GetPackSize()) break;  // the run ended
    h->Unpack();
    const std::string type = h->GetDeviceType(), device = h->GetDeviceName();
    igtl::MessageBase::Pointer body;
    if (type == "IMAGE") body = igtl::ImageMessage::New();
    else if (type == "STRING") body = igtl::StringMessage::New();
    else body = igtl::MessageBase::New();
    body->SetMessageHeader(h);
    body->AllocatePack();
    if (body->GetPackBodySize() > 0 &&
        socket->Receive(body->GetPackBodyPointer(), body->GetPackBodySize()) != body->GetPackBodySize())
      break;
    EXPECT_TRUE(body->Unpack(1) & igtl::MessageHeader::UNPACK_BODY) << type << " " << device << ": bad CRC";
    if (type == "TRANSFORM") {
      if (device == "ImageToReference") ++seen.framePoses;
      if (device == "ProbeToReference") {
        ++seen.probePoses;
        auto tr = igtl::TransformMessage::New();
        tr->SetMessageHeader(h);
        tr->AllocatePack();
        std::memcpy(tr->GetPackBodyPointer(), body->GetPackBodyPointer(), static_cast<std::size_t>(body->GetPackBodySize()));
        tr->Unpack(1);
        igtl::Matrix4x4 m;
        tr->GetMatrix(m);
        bool rigid = true;  // the probe's pose has no pixel spacing in it: unit columns
        for (int col = 0; col < 3; ++col)
          rigid = rigid && std::abs(std::sqrt(m[0][col] * m[0][col] + m[1][col] * m[1][col] + m[2][col] * m[2][col]) - 1.0) < 1e-4;
        if (rigid) ++seen.rigidProbePoses;
      }
      continue;
    }
    if (type == "STRING") {
      auto* str = dynamic_cast<igtl::StringMessage*>(body.GetPointer());
      EXPECT_EQ(device, "ACK_" + std::to_string(nextCommand));
      seen.replies.emplace_back(str->GetString());
      schedule();
      continue;
    }
    EXPECT_EQ(type, "IMAGE") << device;
    if (type != "IMAGE") continue;
    auto* img = dynamic_cast<igtl::ImageMessage*>(body.GetPointer());
    int d[3], sub[3], off[3];
    img->GetDimensions(d);
    img->GetSubVolume(sub, off);
    if (device == "Image_Reference") {
      ++seen.frames;
      if (wait > 0 && --wait == 0) sendNext();
    } else if (device == "RenderedView") {
      EXPECT_EQ(img->GetNumComponents(), 3);
      ++seen.views;
    } else if (device == "Again") {
      ++seen.againVolumes;
    } else if (device == "RecVol_Reference") {
      Seen::Commanded c;
      img->GetDimensions(c.dims);
      img->GetSpacing(c.spacing);
      img->GetOrigin(c.origin);
      seen.commanded.push_back(c);
    } else {
      EXPECT_EQ(device, "Volume_Reference");
      const auto* p = static_cast<const std::uint8_t*>(img->GetScalarPointer());
      const bool whole = sub[0] == d[0] && sub[1] == d[1] && sub[2] == d[2];
      if (whole) {
        ++seen.wholeVolumes;
        std::copy(d, d + 3, seen.dims);
        seen.volume.assign(p, p + static_cast<std::size_t>(d[0]) * d[1] * d[2]);
        if (seen.wholeVolumes == 1) {  // the workflow starts once the volume is there, on its middle half
          float spacing[3], centre[3];
          img->GetSpacing(spacing);
          img->GetOrigin(centre);
          for (int a = 0; a < 3; ++a) {
            seen.roiSpacing[a] = spacing[a];
            seen.roiDims[a] = d[a] / 2;
            seen.roiOrigin[a] = centre[a] - (d[a] - 1) / 2.0 * spacing[a] + (d[a] / 4) * spacing[a];
          }
          schedule();
        }
      } else {
        ++seen.subVolumes;
        EXPECT_TRUE(std::equal(d, d + 3, seen.dims)) << "a sub-volume of another volume";
        for (int z = 0; z < sub[2]; ++z)
          for (int y = 0; y < sub[1]; ++y)
            std::copy_n(p + (static_cast<std::size_t>(z) * sub[1] + y) * sub[0], sub[0],
                        seen.volume.begin() + ((static_cast<std::ptrdiff_t>(off[2]) + z) * d[1] + off[1] + y) * d[0] + off[0]);
      }
    }
  }
  runner.join();
  return seen;
}

// A run with run.igtl_serve, in one process and on 4 ranks: a client of
// Debian's library assembles the volume from the whole one and the
// sub-volume updates of the bricks that changed, and ends with the run's
// volume.mha bit for bit; it gets B-mode frames with their poses and rendered
// views; it drives a reconstruction of a region of interest through
// PlusServer's commands (Start, Suspend, Resume, a snapshot, Stop), each
// answered SUCCESS, the volumes on the region asked for. On 4 ranks with
// --verify: the volume the host assembles from the GPs' changed bricks equals
// the serial pipeline's.
void servesTheRun(const std::string& launcher, const std::string& name) {
  const std::string dir =
      (std::filesystem::temp_directory_path() / ("pp5_igtl_" + name + "_" + std::to_string(::getpid()))).string();
  const std::vector<Step> commands = {
      {R"(<Command Name="StartRecording" OutputFilename="rec.mha"/>)", 0},
      {R"(<Command Name="StartVolumeReconstruction" {ROI} OutputVolDeviceName="RecVol_Reference"/>)", 0},
      {R"(<Command Name="SuspendVolumeReconstruction"/>)", 8},
      {R"(<Command Name="ResumeVolumeReconstruction"/>)", 8},
      {R"(<Command Name="GetVolumeReconstructionSnapshot" ApplyHoleFilling="TRUE"/>)", 8},
      {R"(<Command Name="StopVolumeReconstruction" OutputVolFilename="roi.mha"/>)", 4},
      {R"(<Command Name="StopRecording"/>)", 0},
      {R"(<Command Name="ReconstructVolume" InputSeqFilename="rec.mha" OutputVolFilename="again.mha" OutputVolDeviceName="Again"/>)", 0},
      {R"(<Command Name="NoSuchCommand"/>)", 0},
  };
  const Seen seen = runWithClient(launcher, dir, commands);
  std::printf("%s: %d whole volumes, %d sub-volumes, %d frames, %d poses, %d views; replies:\n", name.c_str(),
              seen.wholeVolumes, seen.subVolumes, seen.frames, seen.framePoses, seen.views);
  for (const auto& r : seen.replies) std::printf("  %s\n", r.c_str());
  EXPECT_GE(seen.frames, 1);
  EXPECT_GE(seen.framePoses, 1);
  EXPECT_GE(seen.probePoses, 1);
  EXPECT_EQ(seen.rigidProbePoses, seen.probePoses);
  EXPECT_GE(seen.views, 1);
  EXPECT_GE(seen.wholeVolumes, 1);
  EXPECT_GE(seen.subVolumes, 1);
  ASSERT_EQ(seen.replies.size(), commands.size());
  for (std::size_t i = 0; i + 1 < commands.size(); ++i)
    EXPECT_NE(seen.replies[i].find("Status=\"SUCCESS\""), std::string::npos) << commands[i].xml << " -> " << seen.replies[i];
  EXPECT_NE(seen.replies.back().find("Status=\"FAIL\""), std::string::npos) << seen.replies.back();
  // Frames went in while it ran, none while suspended: fewer than it ran for.
  int inserted = -1;
  const std::string& stopped = seen.replies[5];
  const std::size_t at = stopped.find(" voxels, ");
  if (at != std::string::npos) inserted = std::atoi(stopped.c_str() + at + 9);
  EXPECT_GT(inserted, 0) << stopped;
  EXPECT_LT(inserted, seen.frames - 8) << stopped;
  // The recording holds what came from its start to its stop, and reconstructs again.
  const auto recorded = pp5::SequenceReader::open(dir + "/rec.mha")->info().frameCount;
  EXPECT_GT(recorded, static_cast<std::uint64_t>(inserted)) << "the recording ran longer than the reconstruction";
  EXPECT_NE(seen.replies[7].find(std::to_string(recorded) + " of " + std::to_string(recorded) + " frames"), std::string::npos)
      << seen.replies[7];
  EXPECT_EQ(seen.againVolumes, 1);
  EXPECT_TRUE(std::filesystem::exists(dir + "/again.mha"));
  ASSERT_EQ(seen.commanded.size(), 2u);  // the snapshot's and the stop's
  for (const auto& c : seen.commanded)
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(c.dims[a], seen.roiDims[a]) << a;
      EXPECT_FLOAT_EQ(c.spacing[a], static_cast<float>(seen.roiSpacing[a])) << a;
      // OpenIGTLink's origin: the region's centre
      EXPECT_NEAR(c.origin[a], seen.roiOrigin[a] + (seen.roiDims[a] - 1) / 2.0 * seen.roiSpacing[a], 1e-3) << a;
    }
  const pp5::Volume roi = pp5::readVolume(dir + "/roi.mha");
  for (int a = 0; a < 3; ++a) {
    EXPECT_EQ(roi.grid.dims[a], seen.roiDims[a]) << a;
    EXPECT_NEAR(roi.grid.origin[a], seen.roiOrigin[a], 1e-3) << a;
  }
  EXPECT_GT(std::count_if(roi.bytes.begin(), roi.bytes.end(), [](std::uint8_t b) { return b != 0; }), 0)
      << "the commanded reconstruction is empty";
  const pp5::Volume v = pp5::readVolume(dir + "/volume.mha").as(pp5::ScalarType::U8);
  ASSERT_EQ(seen.dims[0], v.grid.dims.x);
  ASSERT_EQ(seen.dims[1], v.grid.dims.y);
  ASSERT_EQ(seen.dims[2], v.grid.dims.z);
  EXPECT_TRUE(seen.volume == v.bytes) << "the volume assembled from the updates is not the run's volume.mha";
  if (!::testing::Test::HasFailure()) std::filesystem::remove_all(dir);
}

TEST(IgtlServe, AOneProcessRunServesItsVolumeViewsFramesAndCommands) { servesTheRun("", "serial"); }

TEST(IgtlServe, AFourRankRunServesItsVolumeViewsFramesAndCommands) {
  servesTheRun(std::string(PP5_SOURCE_DIR) + "/scripts/mpirun.sh 4 ", "ranks");
}

// The codec's CRC-64 (eight bytes a step) against Debian's library's (a byte a
// step), over every length to 300, odd starts, and chained calls.
TEST(IgtlServe, TheCrcIsTheLibrarysForEveryLengthAndStart) {
  std::vector<unsigned char> bytes(400);
  std::mt19937 rng(3);
  for (unsigned char& b : bytes) b = static_cast<unsigned char>(rng());
  for (std::size_t start : {0u, 1u, 3u, 7u})
    for (std::size_t n = 0; n <= 300; ++n) {
      const std::uint64_t want = crc64(bytes.data() + start, n, 0);
      ASSERT_EQ(pp5::igtl::codec::crc64(bytes.data() + start, n, 0), want) << "start " << start << ", " << n << " bytes";
      const std::size_t cut = n / 3;
      ASSERT_EQ(pp5::igtl::codec::crc64(bytes.data() + start + cut, n - cut, pp5::igtl::codec::crc64(bytes.data() + start, cut, 0)), want);
    }
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
