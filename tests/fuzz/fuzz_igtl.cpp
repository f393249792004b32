// libFuzzer target: a byte stream from an OpenIGTLink server, decoded by the
// client as a live source decodes it (igtl::Client::decode over a socketpair):
// headers, TRANSFORM and IMAGE bodies, CRCs, pairing. A message the client
// cannot use must be skipped and counted, never crash or end the scan with
// anything but a clean end of stream.
//
// With PP5_FUZZ_SEEDS_DIR set, the target writes its seed streams there
// (TRANSFORMs and IMAGEs packed by the OpenIGTLink library) and exits.
#include <sys/socket.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <igtlImageMessage.h>
#include <igtlTransformMessage.h>

#include "core/error.hpp"
#include "igtl/igtl_client.hpp"
#include "fuzz_util.hpp"

namespace {

void append(std::vector<std::uint8_t>& out, igtl::MessageBase* m) {
  m->Pack();
  const auto* p = static_cast<const std::uint8_t*>(m->GetPackPointer());
  out.insert(out.end(), p, p + m->GetPackSize());
}

std::vector<std::uint8_t> transformMsg(const char* device, double t) {
  std::vector<std::uint8_t> out;
  auto tr = igtl::TransformMessage::New();
  tr->SetDeviceName(device);
  igtl::Matrix4x4 m;
  igtl::IdentityMatrix(m);
  m[0][3] = 10.0f;
  tr->SetMatrix(m);
  auto ts = igtl::TimeStamp::New();
  ts->SetTime(t);
  tr->SetTimeStamp(ts);
  append(out, tr);
  return out;
}

std::vector<std::uint8_t> imageMsg(const char* device, double t, int w, int h, int scalar, int components) {
  std::vector<std::uint8_t> out;
  auto img = igtl::ImageMessage::New();
  img->SetDeviceName(device);
  img->SetDimensions(w, h, 1);
  img->SetSpacing(0.2f, 0.2f, 1.0f);
  img->SetScalarType(scalar);
  img->SetNumComponents(components);
  img->AllocateScalars();
  auto* px = static_cast<std::uint8_t*>(img->GetScalarPointer());
  for (int i = 0; i < img->GetImageSize(); ++i) px[i] = static_cast<std::uint8_t>(i * 7);
  auto ts = igtl::TimeStamp::New();
  ts->SetTime(t);
  img->SetTimeStamp(ts);
  append(out, img);
  return out;
}

void writeSeeds(const std::string& dir) {
  auto put = [&](const std::string& name, const std::vector<std::vector<std::uint8_t>>& parts) {
    std::ofstream f(dir + "/seed-" + name, std::ios::binary);
    for (const auto& p : parts) f.write(reinterpret_cast<const char*>(p.data()), static_cast<std::streamsize>(p.size()));
  };
  put("pair", {transformMsg("ProbeToTracker", 1.0), transformMsg("ReferenceToTracker", 1.0),
               imageMsg("Image", 1.0, 16, 12, igtl::ImageMessage::TYPE_UINT8, 1)});
  put("image16", {imageMsg("Image_Reference", 2.0, 8, 8, igtl::ImageMessage::TYPE_UINT16, 1)});
  put("rgb", {imageMsg("Image", 3.0, 8, 8, igtl::ImageMessage::TYPE_UINT8, 3)});
  put("transforms", {transformMsg("StylusToTracker", 4.0), transformMsg("ProbeToTracker", 4.01)});
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  pp5::fuzz::writeSeedsIfAsked(writeSeeds);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  int fds[2];
  if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, fds) != 0) return 0;
  std::thread writer([&] {
    std::size_t done = 0;
    while (done < size) {
      const ssize_t n = ::write(fds[1], data + done, size - done);
      if (n <= 0) break;
      done += static_cast<std::size_t>(n);
    }
    ::close(fds[1]);
  });
  pp5::igtl::ClientOptions opt;
  pp5::igtl::Client client(opt);
  std::size_t frames = 0;
  client.decode(fds[0], [&](pp5::Frame&& f) {
    ++frames;
    if (f.byteSize() != f.pixels.size()) std::abort();  // a frame must hold what it says
  });
  writer.join();
  return 0;
}
