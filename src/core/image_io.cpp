#include "core/image_io.hpp"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>

#include <OpenImageIO/imageio.h>

#include "core/error.hpp"

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
  out->close();
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

struct AnimatedGif::Impl {
  std::filesystem::path final, tmp;
  std::unique_ptr<OIIO::ImageOutput> out;
  OIIO::ImageSpec spec;
};

AnimatedGif::AnimatedGif(const std::string& path, int width, int height, double fps) : impl_(std::make_unique<Impl>()) {
  PP5_CHECK_GT(width, 0);
  PP5_CHECK_GT(height, 0);
  PP5_CHECK(fps > 0.0);
  impl_->final = path;
  impl_->tmp = impl_->final.parent_path() / (".tmp-" + impl_->final.filename().string());
  impl_->out = OIIO::ImageOutput::create(impl_->tmp.string());
  if (!impl_->out) inputError(path, "cannot write a GIF ({})", OIIO::geterror());
  impl_->spec = OIIO::ImageSpec(width, height, 3, OIIO::TypeDesc::UINT8);
  // GIF stores frame delays in hundredths of a second.
  const int rate[2] = {static_cast<int>(std::lround(fps * 100.0)), 100};
  impl_->spec.attribute("FramesPerSecond", OIIO::TypeRational, rate);
  impl_->spec.attribute("oiio:Movie", 1);
  impl_->spec.attribute("gif:LoopCount", 0);
}

AnimatedGif::~AnimatedGif() {
  if (impl_ && impl_->out) {
    if (frames_ > 0) impl_->out->close();
    std::error_code ec;
    std::filesystem::remove(impl_->tmp, ec);
  }
}

void AnimatedGif::add(const std::uint8_t* rgb) {
  PP5_CHECK(impl_->out != nullptr);
  const auto mode = frames_ == 0 ? OIIO::ImageOutput::Create : OIIO::ImageOutput::AppendSubimage;
  if (!impl_->out->open(impl_->tmp.string(), impl_->spec, mode))
    inputError(impl_->final.string(), "cannot add frame {}: {}", frames_, impl_->out->geterror());
  if (!impl_->out->write_image(OIIO::TypeDesc::UINT8, rgb))
    inputError(impl_->final.string(), "cannot write frame {}: {}", frames_, impl_->out->geterror());
  ++frames_;
}

void AnimatedGif::close() {
  PP5_CHECK(impl_->out != nullptr);
  if (frames_ == 0) inputError(impl_->final.string(), "an animation needs at least one frame");
  impl_->out->close();
  impl_->out.reset();
  std::error_code ec;
  std::filesystem::rename(impl_->tmp, impl_->final, ec);
  if (ec) inputError(impl_->final.string(), "cannot rename the finished animation into place: {}", ec.message());
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
