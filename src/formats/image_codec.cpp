// The PNG (and other OpenImageIO formats') encoder and decoder, built as a
// module of its own that formats/image_io.cpp loads on first use. Loading
// OpenImageIO maps Debian's whole tree of its plugins' libraries (some 260)
// and takes a third of a second of CPU before main; most processes (the GP
// and PP ranks, most tests) never write or read an image, and now never pay
// it (docs/dependencies.md). Plain C entry points: nothing C++ crosses the
// module's edge, exceptions included.
#include <cstdlib>
#include <cstring>
#include <exception>
#include <string>
#include <vector>

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

namespace {

void say(char* err, std::size_t n, const std::string& what) {
  if (!err || n == 0) return;
  std::strncpy(err, what.c_str(), n - 1);
  err[n - 1] = '\0';
}

}  // namespace

extern "C" {

// Encodes 8-bit pixels in the format the extension of `path` names (nothing
// is written to `path`); 0 and *out (free with pp5_codec_free), or 1 and `err`.
__attribute__((visibility("default"))) int pp5_codec_encode(const char* path, int width, int height, int channels,
                                                           const unsigned char* px, unsigned char** out,
                                                           std::size_t* outSize, char* err, std::size_t errSize) {
  try {
    auto o = OIIO::ImageOutput::create(path);  // the format by the extension; nothing is opened
    if (!o) return say(err, errSize, "cannot write an image of this type (" + OIIO::geterror() + ")"), 1;
    if (!o->supports("ioproxy")) return say(err, errSize, "the image writer cannot encode to memory"), 1;
    std::vector<unsigned char> encoded;
    OIIO::Filesystem::IOVecOutput memory(encoded);
    o->set_ioproxy(&memory);
    OIIO::ImageSpec spec(width, height, channels, OIIO::TypeDesc::UINT8);
    // Level 1 is ~3x faster than the default for noisy ultrasound content,
    // for files only a little larger.
    spec.attribute("png:compressionLevel", 1);
    if (!o->open(path, spec)) return say(err, errSize, "cannot encode: " + o->geterror()), 1;
    if (!o->write_image(OIIO::TypeDesc::UINT8, px) || !o->close())
      return say(err, errSize, "cannot encode: " + o->geterror()), 1;
    *out = static_cast<unsigned char*>(std::malloc(encoded.size() ? encoded.size() : 1));
    if (!*out) return say(err, errSize, "out of memory"), 1;
    std::memcpy(*out, encoded.data(), encoded.size());
    *outSize = encoded.size();
    return 0;
  } catch (const std::exception& e) {
    return say(err, errSize, e.what()), 1;
  }
}

// Decodes the image file `path` to 8-bit pixels; 0 and *px (free with
// pp5_codec_free), or 1 and `err`.
__attribute__((visibility("default"))) int pp5_codec_decode(const char* path, int* width, int* height, int* channels,
                                                           unsigned char** px, char* err, std::size_t errSize) {
  try {
    auto in = OIIO::ImageInput::open(path);
    if (!in) return say(err, errSize, "cannot read image: " + OIIO::geterror()), 1;
    const OIIO::ImageSpec& spec = in->spec();
    const std::size_t n = static_cast<std::size_t>(spec.width) * spec.height * spec.nchannels;
    *px = static_cast<unsigned char*>(std::malloc(n ? n : 1));
    if (!*px) return say(err, errSize, "out of memory"), 1;
    if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::UINT8, *px)) {
      std::free(*px);
      *px = nullptr;
      return say(err, errSize, "cannot decode image: " + in->geterror()), 1;
    }
    in->close();
    *width = spec.width;
    *height = spec.height;
    *channels = spec.nchannels;
    return 0;
  } catch (const std::exception& e) {
    return say(err, errSize, e.what()), 1;
  }
}

__attribute__((visibility("default"))) void pp5_codec_free(void* p) { std::free(p); }

}  // extern "C"
