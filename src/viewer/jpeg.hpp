#pragma once
// JPEG for the images the viewer streams (libturbojpeg): an RGB image of
// 8 bits per channel in, the bytes of a baseline JPEG out. A compressor is
// kept per Encoder, so a stream of images reuses it.
#include <cstdint>
#include <memory>
#include <string>

namespace pp5::viewer {

class JpegEncoder {
public:
  JpegEncoder();
  ~JpegEncoder();
  JpegEncoder(const JpegEncoder&) = delete;
  JpegEncoder& operator=(const JpegEncoder&) = delete;
  // width * height * 3 bytes, row-major; quality 1..100. InvariantError for a
  // bad size or quality (the caller's mistake, not the user's).
  std::string encode(const std::uint8_t* rgb, int width, int height, int quality);

private:
  void* handle_ = nullptr;
};

// The decoded image, for tests: width * height * 3 bytes.
struct DecodedJpeg {
  int width = 0, height = 0;
  std::string rgb;
};
DecodedJpeg decodeJpeg(const std::string& jpeg);  // InputError when it is not a JPEG

}  // namespace pp5::viewer
