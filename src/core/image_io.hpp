#pragma once
// 2D image output through OpenImageIO (PNG, EXR, TIFF, ... by extension).
// Writes are atomic: a temporary file in the same folder, renamed when done.
#include <cstdint>
#include <string>
#include <vector>

namespace pp5 {

// 8-bit grey image, row-major, `width` bytes per row.
void writeGrayPng(const std::string& path, int width, int height, const std::uint8_t* pixels);
// 8-bit RGBA image, row-major.
void writeRgbaPng(const std::string& path, int width, int height, const std::uint8_t* rgba);

// An 8-bit image read back (tests, docs). channels = 1, 3 or 4.
struct Image8 {
  int width = 0, height = 0, channels = 0;
  std::vector<std::uint8_t> pixels;
};
Image8 readImage8(const std::string& path);

}  // namespace pp5
