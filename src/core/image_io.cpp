#include "core/image_io.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <vector>

#include <OpenImageIO/imageio.h>
#include <gif_lib.h>

#include "core/error.hpp"
#include "core/io_util.hpp"

namespace pp5 {
namespace {

void writeImage(const std::string& path, int width, int height, int channels, const std::uint8_t* px) {
  PP5_CHECK_GT(width, 0);
  PP5_CHECK_GT(height, 0);
  // Keep the real extension on the temporary name: OpenImageIO picks the format from it.
  const std::filesystem::path final(path);
  const std::filesystem::path tmp =
      final.parent_path() / (".tmp-" + final.stem().string() + final.extension().string());
  auto out = OIIO::ImageOutput::create(tmp.string());
  if (!out) inputError(path, "cannot write an image of this type ({})", OIIO::geterror());
  OIIO::ImageSpec spec(width, height, channels, OIIO::TypeDesc::UINT8);
  // Level 1 is ~3x faster than the default for noisy ultrasound content, for
  // files only a little larger.
  spec.attribute("png:compressionLevel", 1);
  if (!out->open(tmp.string(), spec)) inputError(path, "cannot open for writing: {}", out->geterror());
  if (!out->write_image(OIIO::TypeDesc::UINT8, px)) {
    const std::string why = out->geterror();
    out->close();
    std::filesystem::remove(tmp);
    inputError(path, "write failed: {}", why);
  }
  // A full disk may show only when the last buffer goes out: checked, and the
  // bytes on disk before the name is taken.
  if (!out->close() || !io::syncFile(tmp.string())) {
    const std::string why = out->geterror();
    std::filesystem::remove(tmp);
    inputError(path, "write failed: {}", why.empty() ? std::string("the file could not be completed") : why);
  }
  std::error_code ec;
  std::filesystem::rename(tmp, final, ec);
  if (ec) inputError(path, "cannot rename the finished image into place: {}", ec.message());
}

}  // namespace

void writeGrayPng(const std::string& path, int width, int height, const std::uint8_t* pixels) {
  writeImage(path, width, height, 1, pixels);
}

void writeRgbaPng(const std::string& path, int width, int height, const std::uint8_t* rgba) {
  writeImage(path, width, height, 4, rgba);
}

void writeRgbPng(const std::string& path, int width, int height, const std::uint8_t* rgb) {
  writeImage(path, width, height, 3, rgb);
}

// GIF with giflib, each frame whole with its own palette (median cut, no
// dithering) and no transparency. OpenImageIO's writer (gif.h) encodes a
// frame as a delta: it keeps the previous frame's pixel wherever the new
// colour quantises close to the old one, which left fragments of earlier
// views in orbit.gif (tests/gif_frames.py).
struct AnimatedGif::Impl {
  std::filesystem::path final, tmp;
  GifFileType* gif = nullptr;
  int width = 0, height = 0, delay = 0;
  void fail(const char* what, int error) const {
    inputError(final.string(), "cannot write the animation ({}): {}", what, GifErrorString(error));
  }
};

AnimatedGif::AnimatedGif(const std::string& path, int width, int height, double fps) : impl_(std::make_unique<Impl>()) {
  PP5_CHECK_GT(width, 0);
  PP5_CHECK_GT(height, 0);
  PP5_CHECK(fps > 0.0);
  if (width > 65535 || height > 65535) inputError(path, "a GIF is at most 65535 pixels a side");
  Impl& I = *impl_;
  I.final = path;
  I.tmp = I.final.parent_path() / (".tmp-" + I.final.filename().string());
  I.width = width;
  I.height = height;
  I.delay = std::max(1, static_cast<int>(std::lround(100.0 / fps)));  // hundredths of a second
  int err = 0;
  I.gif = EGifOpenFileName(I.tmp.string().c_str(), false, &err);
  if (!I.gif) I.fail("open", err);
  EGifSetGifVersion(I.gif, true);
  if (EGifPutScreenDesc(I.gif, width, height, 8, 0, nullptr) == GIF_ERROR) I.fail("screen", I.gif->Error);
  // Loop forever (the NETSCAPE2.0 application extension).
  const GifByteType loop[3] = {1, 0, 0};
  if (EGifPutExtensionLeader(I.gif, APPLICATION_EXT_FUNC_CODE) == GIF_ERROR ||
      EGifPutExtensionBlock(I.gif, 11, "NETSCAPE2.0") == GIF_ERROR || EGifPutExtensionBlock(I.gif, 3, loop) == GIF_ERROR ||
      EGifPutExtensionTrailer(I.gif) == GIF_ERROR)
    I.fail("loop", I.gif->Error);
}

AnimatedGif::~AnimatedGif() {
  if (impl_ && impl_->gif) {
    int err = 0;
    EGifCloseFile(impl_->gif, &err);
    std::error_code ec;
    std::filesystem::remove(impl_->tmp, ec);
  }
}

void AnimatedGif::add(const std::uint8_t* rgb) {
  Impl& I = *impl_;
  PP5_CHECK(I.gif != nullptr);
  const std::size_t n = static_cast<std::size_t>(I.width) * static_cast<std::size_t>(I.height);
  std::vector<GifByteType> r(n), g(n), b(n), index(n);
  for (std::size_t i = 0; i < n; ++i) {
    r[i] = rgb[3 * i];
    g[i] = rgb[3 * i + 1];
    b[i] = rgb[3 * i + 2];
  }
  int colours = 256;
  GifColorType palette[256] = {};
  if (GifQuantizeBuffer(static_cast<unsigned>(I.width), static_cast<unsigned>(I.height), &colours, r.data(), g.data(),
                        b.data(), index.data(), palette) == GIF_ERROR)
    inputError(I.final.string(), "cannot quantise frame {}", frames_);
  ColorMapObject* map = GifMakeMapObject(256, palette);
  if (!map) inputError(I.final.string(), "cannot make the palette of frame {}", frames_);
  GraphicsControlBlock gcb{};
  gcb.DisposalMode = DISPOSE_DO_NOT;  // every frame covers the whole image
  gcb.UserInputFlag = false;
  gcb.DelayTime = I.delay;
  gcb.TransparentColor = NO_TRANSPARENT_COLOR;
  GifByteType ext[4];
  const auto extLen = static_cast<int>(EGifGCBToExtension(&gcb, ext));
  bool ok = EGifPutExtension(I.gif, GRAPHICS_EXT_FUNC_CODE, extLen, ext) != GIF_ERROR &&
            EGifPutImageDesc(I.gif, 0, 0, I.width, I.height, false, map) != GIF_ERROR;
  for (int y = 0; ok && y < I.height; ++y)
    ok = EGifPutLine(I.gif, index.data() + static_cast<std::size_t>(y) * I.width, I.width) != GIF_ERROR;
  GifFreeMapObject(map);
  if (!ok) inputError(I.final.string(), "cannot write frame {}: {}", frames_, GifErrorString(I.gif->Error));
  ++frames_;
}

void AnimatedGif::close() {
  Impl& I = *impl_;
  PP5_CHECK(I.gif != nullptr);
  if (frames_ == 0) inputError(I.final.string(), "an animation needs at least one frame");
  int err = 0;
  const int rc = EGifCloseFile(I.gif, &err);
  I.gif = nullptr;
  if (rc == GIF_ERROR || !io::syncFile(I.tmp.string())) {
    std::error_code rm;
    std::filesystem::remove(I.tmp, rm);  // no stray temporary beside the outputs
    I.fail("close", rc == GIF_ERROR ? err : E_GIF_ERR_WRITE_FAILED);
  }
  std::error_code ec;
  std::filesystem::rename(I.tmp, I.final, ec);
  if (ec) inputError(I.final.string(), "cannot rename the finished animation into place: {}", ec.message());
}

Image8 readImage8(const std::string& path) {
  auto in = OIIO::ImageInput::open(path);
  if (!in) inputError(path, "cannot read image: {}", OIIO::geterror());
  const OIIO::ImageSpec& spec = in->spec();
  Image8 img;
  img.width = spec.width;
  img.height = spec.height;
  img.channels = spec.nchannels;
  img.pixels.resize(static_cast<std::size_t>(img.width) * img.height * img.channels);
  if (!in->read_image(0, 0, 0, img.channels, OIIO::TypeDesc::UINT8, img.pixels.data()))
    inputError(path, "cannot decode image: {}", in->geterror());
  in->close();
  return img;
}

}  // namespace pp5
