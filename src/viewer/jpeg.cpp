#include "viewer/jpeg.hpp"

#include <turbojpeg.h>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::viewer {

JpegEncoder::JpegEncoder() : handle_(tjInitCompress()) {
  if (!handle_) throw InvariantError(fmt::format("libturbojpeg: {}", tjGetErrorStr2(nullptr)));
}

JpegEncoder::~JpegEncoder() { tjDestroy(static_cast<tjhandle>(handle_)); }

std::string JpegEncoder::encode(const std::uint8_t* rgb, int width, int height, int quality) {
  PP5_CHECK(width > 0 && height > 0);
  PP5_CHECK(quality >= 1 && quality <= 100);
  unsigned char* out = nullptr;
  unsigned long size = 0;
  // 4:2:0 chroma, as a video stream would: the images are mostly grey.
  if (tjCompress2(static_cast<tjhandle>(handle_), rgb, width, 0, height, TJPF_RGB, &out, &size, TJSAMP_420, quality,
                  TJFLAG_FASTDCT) != 0) {
    const std::string error = tjGetErrorStr2(static_cast<tjhandle>(handle_));
    tjFree(out);
    throw InvariantError(fmt::format("libturbojpeg: {}", error));
  }
  std::string jpeg(reinterpret_cast<const char*>(out), size);
  tjFree(out);
  return jpeg;
}

DecodedJpeg decodeJpeg(const std::string& jpeg) {
  const tjhandle h = tjInitDecompress();
  if (!h) throw InvariantError(fmt::format("libturbojpeg: {}", tjGetErrorStr2(nullptr)));
  DecodedJpeg d;
  int subsamp = 0, colorspace = 0;
  const auto* in = reinterpret_cast<const unsigned char*>(jpeg.data());
  if (tjDecompressHeader3(h, in, jpeg.size(), &d.width, &d.height, &subsamp, &colorspace) != 0) {
    tjDestroy(h);
    throw InputError("not a JPEG image");
  }
  d.rgb.resize(static_cast<std::size_t>(d.width) * static_cast<std::size_t>(d.height) * 3);
  const int rc = tjDecompress2(h, in, jpeg.size(), reinterpret_cast<unsigned char*>(d.rgb.data()), d.width, 0,
                               d.height, TJPF_RGB, 0);
  tjDestroy(h);
  if (rc != 0) throw InputError("a broken JPEG image");
  return d;
}

}  // namespace pp5::viewer
