// Writes an animated GIF through pp5echo's writer (formats/image_io AnimatedGif)
// together with each frame's source as raw RGB, for tests/gif_frames.py to
// decode the animation and compare frame by frame. The frames are like an
// orbit's: a bright shape that turns over a dark, slightly noisy background,
// so that every frame uncovers pixels the one before had lit.
// Usage: gif_writer OUT_DIR
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <vector>

#include "formats/image_io.hpp"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: gif_writer OUT_DIR\n");
    return 2;
  }
  const std::filesystem::path dir(argv[1]);
  std::filesystem::create_directories(dir);
  const int w = 160, h = 120, n = 24;
  pp5::AnimatedGif gif((dir / "anim.gif").string(), w, h, 12.0);
  std::vector<std::uint8_t> rgb(static_cast<std::size_t>(w) * h * 3);
  for (int f = 0; f < n; ++f) {
    const double a = 2.0 * 3.14159265358979 * f / n;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const double u = (x - w / 2.0) * std::cos(a) + (y - h / 2.0) * std::sin(a);
        const double v = -(x - w / 2.0) * std::sin(a) + (y - h / 2.0) * std::cos(a);
        const bool bar = std::abs(u) < 50 && std::abs(v) < 10;
        const int noise = static_cast<int>((x * 7 + y * 13 + f * 3) % 9);
        std::uint8_t* p = &rgb[(static_cast<std::size_t>(y) * w + x) * 3];
        // More colours than a GIF palette holds: the writer must quantise.
        p[0] = static_cast<std::uint8_t>(bar ? 140 + (x % 100) : 10 + noise);
        p[1] = static_cast<std::uint8_t>(bar ? 100 + y : 10 + noise + (x % 5));
        p[2] = static_cast<std::uint8_t>(bar ? 60 + ((x + y) % 60) : 20 + noise);
      }
    gif.add(rgb.data());
    std::ofstream((dir / ("frame" + std::to_string(f) + ".rgb")).string(), std::ios::binary)
        .write(reinterpret_cast<const char*>(rgb.data()), static_cast<std::streamsize>(rgb.size()));
  }
  gif.close();
  std::printf("%d %d %d\n", w, h, n);
  return 0;
}
