#include "formats/image_io.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <vector>

#include <dlfcn.h>

#include <fmt/format.h>
#include <gif_lib.h>

#include "core/error.hpp"
#include "core/io_util.hpp"

namespace pp5 {
namespace {

// The image codec module (formats/image_codec.cpp), loaded on first use: the
// build tree's, PP5_IMAGE_CODEC's, or the one installed beside the program.
struct Codec {
  int (*encode)(const char*, int, int, int, const unsigned char*, unsigned char**, std::size_t*, char*, std::size_t);
  int (*decode)(const char*, int*, int*, int*, unsigned char**, char*, std::size_t);
  void (*release)(void*);
};

std::vector<std::string> codecCandidates() {
  std::vector<std::string> out;
  if (const char* env = std::getenv("PP5_IMAGE_CODEC"); env && *env) out.emplace_back(env);
  std::error_code ec;
  const auto exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (!ec) out.push_back((exe.parent_path().parent_path() / "lib" / "pp5echo" / PP5_IMAGE_CODEC_NAME).string());
  out.emplace_back(PP5_IMAGE_CODEC_BUILT);
  return out;
}

const Codec& codec() {
  static const Codec c = [] {
    std::string tried;
    for (const std::string& path : codecCandidates()) {
      if (void* h = ::dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL)) {
        Codec k{};
        k.encode = reinterpret_cast<decltype(k.encode)>(::dlsym(h, "pp5_codec_encode"));
        k.decode = reinterpret_cast<decltype(k.decode)>(::dlsym(h, "pp5_codec_decode"));
        k.release = reinterpret_cast<decltype(k.release)>(::dlsym(h, "pp5_codec_free"));
        if (k.encode && k.decode && k.release) return k;
        tried += fmt::format("; {}: not the image codec module", path);
      } else {
        tried += fmt::format("; {}", ::dlerror());
      }
    }
    throw InputError("cannot load the image codec module (OpenImageIO)" + tried +
                     " (set PP5_IMAGE_CODEC to its path)");
  }();
  return c;
}

void writeImage(const std::string& path, int width, int height, int channels, const std::uint8_t* px) {
  PP5_CHECK_GT(width, 0);
  PP5_CHECK_GT(height, 0);
  // Encoded in memory, then written with io::AtomicFile, which checks every
  // write, syncs and renames: OpenImageIO's PNG writer reported success for a
  // file the disk had cut short (found with `ulimit -f`).
  const Codec& k = codec();
  unsigned char* encoded = nullptr;
  std::size_t n = 0;
  char err[512] = {};
  if (k.encode(path.c_str(), width, height, channels, px, &encoded, &n, err, sizeof err) != 0) inputError(path, "{}", err);
  const std::unique_ptr<unsigned char, void (*)(void*)> owned(encoded, k.release);
  io::AtomicFile file(path);
  file.write(encoded, n);
  file.commit();
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
  std::filesystem::path final;
  // Streamed to a temporary beside the final name as frames come (a long
  // run's animation need not fit in memory); every write checked, renamed into
  // place by close().
  std::unique_ptr<io::AtomicFile> file;
  std::string writeError;  // why the last write failed (giflib only sees a short count)
  GifFileType* gif = nullptr;
  int width = 0, height = 0, delay = 0;
  void fail(const char* what, int error) const {
    if (!writeError.empty()) inputError(final.string(), "cannot write the animation ({}): {}", what, writeError);
    inputError(final.string(), "cannot write the animation ({}): {}", what, GifErrorString(error));
  }
  static int append(GifFileType* g, const GifByteType* data, int n) {
    auto* self = static_cast<Impl*>(g->UserData);
    try {  // no exception may cross giflib's C frames
      self->file->write(data, static_cast<std::size_t>(n));
      return n;
    } catch (const std::exception& e) {
      self->writeError = e.what();
      return 0;
    }
  }
};

AnimatedGif::AnimatedGif(const std::string& path, int width, int height, double fps) : impl_(std::make_unique<Impl>()) {
  PP5_CHECK_GT(width, 0);
  PP5_CHECK_GT(height, 0);
  PP5_CHECK(fps > 0.0);
  if (width > 65535 || height > 65535) inputError(path, "a GIF is at most 65535 pixels a side");
  Impl& I = *impl_;
  I.final = path;
  I.width = width;
  I.height = height;
  I.delay = std::max(1, static_cast<int>(std::lround(100.0 / fps)));  // hundredths of a second
  int err = 0;
  I.file = std::make_unique<io::AtomicFile>(path);
  I.gif = EGifOpen(&I, &Impl::append, &err);
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
  if (!ok)
    inputError(I.final.string(), "cannot write frame {}: {}", frames_,
               I.writeError.empty() ? std::string(GifErrorString(I.gif->Error)) : I.writeError);
  ++frames_;
}

void AnimatedGif::close() {
  Impl& I = *impl_;
  PP5_CHECK(I.gif != nullptr);
  if (frames_ == 0) inputError(I.final.string(), "an animation needs at least one frame");
  int err = 0;
  const int rc = EGifCloseFile(I.gif, &err);
  I.gif = nullptr;
  if (rc == GIF_ERROR) I.fail("close", err);
  I.file->commit();
}

Image8 readImage8(const std::string& path) {
  const Codec& k = codec();
  Image8 img;
  unsigned char* px = nullptr;
  char err[512] = {};
  if (k.decode(path.c_str(), &img.width, &img.height, &img.channels, &px, err, sizeof err) != 0)
    inputError(path, "{}", err);
  const std::unique_ptr<unsigned char, void (*)(void*)> owned(px, k.release);
  img.pixels.assign(px, px + static_cast<std::size_t>(img.width) * img.height * img.channels);
  return img;
}

}  // namespace pp5
