#include "core/image_io.hpp"

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
