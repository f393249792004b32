#pragma once
// 2D image output through OpenImageIO (PNG, EXR, TIFF, ... by extension).
// Writes are atomic: a temporary file in the same folder, renamed when done.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace pp5 {

// 8-bit grey image, row-major, `width` bytes per row.
void writeGrayPng(const std::string& path, int width, int height, const std::uint8_t* pixels);
// 8-bit RGBA image, row-major.
void writeRgbaPng(const std::string& path, int width, int height, const std::uint8_t* rgba);

// 8-bit RGB image, row-major.
void writeRgbPng(const std::string& path, int width, int height, const std::uint8_t* rgb);

// An animated GIF (looping forever), written frame by frame under a temporary
// name and renamed into place by close(), so an interrupted run leaves no
// half-written file. GIF's 256-colour palette per frame is OpenImageIO's.
class AnimatedGif {
public:
  AnimatedGif(const std::string& path, int width, int height, double framesPerSecond);
  ~AnimatedGif();  // discards an unclosed file
  AnimatedGif(const AnimatedGif&) = delete;
  AnimatedGif& operator=(const AnimatedGif&) = delete;
  void add(const std::uint8_t* rgb);  // width * height * 3 bytes
  void close();                       // an animation with no frame is an error
  int frames() const { return frames_; }

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int frames_ = 0;
};

// An 8-bit image read back (tests, docs). channels = 1, 3 or 4.
struct Image8 {
  int width = 0, height = 0, channels = 0;
  std::vector<std::uint8_t> pixels;
};
Image8 readImage8(const std::string& path);

}  // namespace pp5
