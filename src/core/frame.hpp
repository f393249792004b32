#pragma once
// One 2D ultrasound frame with its tracking data, as a PLUS sequence stores it.
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/transform.hpp"

namespace pp5 {

enum class PixelType : std::uint8_t { U8, U16 };

inline int bytesPerPixel(PixelType t) { return t == PixelType::U8 ? 1 : 2; }

// A transform as recorded for one frame: "ProbeToTracker" with its status.
struct FrameTransform {
  std::string name;  // "ProbeToTracker" (without the "Transform" suffix of the file key)
  Mat4 matrix{1.0};
  bool valid = true;  // TransformStatus == OK
};

struct Frame {
  int width = 0;
  int height = 0;
  PixelType pixelType = PixelType::U8;
  // Row-major, little-endian for U16, in MF orientation once read.
  std::vector<std::uint8_t> pixels;

  std::uint64_t index = 0;    // position in the stream (Seq_FrameNNNN)
  double timestamp = 0.0;     // seconds
  bool imageValid = true;     // ImageStatus (or Status) == OK

  std::vector<FrameTransform> transforms;  // in file order
  // Any other per-frame fields ("Seq_Frame0003_<key> = value"), in file order.
  std::vector<std::pair<std::string, std::string>> customFields;

  std::size_t byteSize() const {
    return static_cast<std::size_t>(width) * static_cast<std::size_t>(height) *
           static_cast<std::size_t>(bytesPerPixel(pixelType));
  }
  void allocate(int w, int h, PixelType t) {
    width = w;
    height = h;
    pixelType = t;
    pixels.assign(byteSize(), 0);
  }
  // Pixel value as a number, whatever the pixel type. (x: column, y: row)
  double value(int x, int y) const {
    const std::size_t i = static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x);
    if (pixelType == PixelType::U8) return pixels[i];
    return static_cast<double>(static_cast<std::uint16_t>(pixels[2 * i] | (pixels[2 * i + 1] << 8)));
  }
  std::uint8_t* u8() { return pixels.data(); }
  const std::uint8_t* u8() const { return pixels.data(); }

  const FrameTransform* findTransform(const std::string& name) const {
    for (const auto& t : transforms)
      if (t.name == name) return &t;
    return nullptr;
  }
  void setTransform(const std::string& name, const Mat4& m, bool valid = true) {
    for (auto& t : transforms)
      if (t.name == name) {
        t.matrix = m;
        t.valid = valid;
        return;
      }
    transforms.push_back({name, m, valid});
  }
  const std::string* findField(const std::string& key) const {
    for (const auto& kv : customFields)
      if (kv.first == key) return &kv.second;
    return nullptr;
  }
};

}  // namespace pp5
