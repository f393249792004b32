// The ray cache's settings ([render.cache]), its memory, and its images as 8-bit pixels.
#include <bit>

#include <fmt/format.h>

#include "core/config.hpp"
#include "core/error.hpp"
#include "rendering/composite_kernels.hpp"
#include "rendering/ray_cache.hpp"

namespace pp5::pp {

using composite::kMaxBlockSize;
using composite::toU8;

CompositeMode compositeModeFromName(const std::string& name) { return enumFromName<CompositeMode>(name); }
const char* compositeModeName(CompositeMode m) { return enumName(m).data(); }
SampleFormat sampleFormatFromName(const std::string& name) { return enumFromName<SampleFormat>(name); }
const char* sampleFormatName(SampleFormat f) { return enumName(f).data(); }

std::size_t sampleFormatBytes(SampleFormat f) {
  switch (f) {
    case SampleFormat::Rgba8: return 4;
    case SampleFormat::Half: return 8;
    case SampleFormat::Float: return 16;
  }
  return 0;
}



void RayCacheSettings::validate() const {
  checkedEnum(format);
  if (blockSize < 1 || blockSize > kMaxBlockSize || !std::has_single_bit(static_cast<unsigned>(blockSize)))
    throw InputError(fmt::format("render.cache.block_size = {}: must be a power of two from 1 to {}", blockSize,
                                 kMaxBlockSize));
  if (!(terminationAlpha >= 0.5 && terminationAlpha <= 1.0))
    throw InputError(fmt::format("render.cache.termination_alpha = {}: must be within 0.5 .. 1", terminationAlpha));
  if (!(additiveScale > 0.0)) throw InputError(fmt::format("render.cache.additive_scale = {}: must be > 0", additiveScale));
}

void registerOptions(ConfigSchema& c, RayCacheSettings& s) {
  c.section("render.cache",
            "The pixel processor's ray-sample cache: blocks of samples with partial composites, the storage "
            "format of a sample, early ray termination.");
  c.option("render.cache.block_size", &s.blockSize, 32, 1, kMaxBlockSize,
           "Samples per block, a power of two. A changed sample recomposites its block, then the ray's block "
           "partials; each block also costs 17 bytes of partial and flag, and termination stops at a block "
           "boundary.");
  enumOption(c, "render.cache.format", &s.format, SampleFormat::Half,
           "How a sample's premultiplied colour and opacity are stored: `half` (8 bytes, IEEE binary16; images "
           "within a small fraction of an 8-bit level of `float`), `float` (16 bytes, exact) or `rgba8` (4 bytes; "
           "quantises the small per-sample opacities of a fine lattice, and images are off by tens of levels).");
  c.option("render.cache.early_termination", &s.earlyTermination, true,
           "\"over\": stop walking a ray's blocks once its accumulated alpha reaches `termination_alpha`.");
  c.option("render.cache.termination_alpha", &s.terminationAlpha, 1.0 - 1.0 / 512.0, 0.5, 1.0,
           "Accumulated alpha that ends a ray (early termination); what lies behind can change the pixel by at "
           "most 1 - termination_alpha. 1 stops only at full opacity, which changes nothing.");
  c.option("render.cache.additive_scale", &s.additiveScale, 0.02, 1e-6, 1e6,
           "\"additive\": the integral of the grey value along the ray (grey level x mm) times this is the grey "
           "level shown through render.value_window; 0.02 shows the mean over 50 mm.");
}

std::size_t RayCache::memoryBytes() const {
  return rays_.capacity() * sizeof(Ray) + samples8_.size() + samples16_.size() * sizeof(std::uint16_t) +
         samples32_.size() * sizeof(float) + partials_.capacity() * sizeof(Partial) + dirty_.capacity() +
         touched_.capacity() +
         dirtyRays_.capacity() * sizeof(std::uint32_t) +
         image_.rgba.capacity() * sizeof(float);
}

// ---------------------------------------------------------------------------

std::vector<std::uint8_t> toRgb8(const TileImage& im) {
  std::vector<std::uint8_t> px(static_cast<std::size_t>(im.width) * static_cast<std::size_t>(im.height) * 3);
  const float black[3] = {0.0f, 0.0f, 0.0f};
  toRgb8(im, black, px.data());
  return px;
}

void toRgb8(const TileImage& im, const float background[3], std::uint8_t* rgb) {
  const std::size_t n = static_cast<std::size_t>(im.width) * im.height;
  for (std::size_t i = 0; i < n; ++i) {
    const float* p = im.rgba.data() + 4 * i;
    const float t = 1.0f - p[3];
    for (int c = 0; c < 3; ++c) rgb[3 * i + c] = toU8(p[c] + t * background[c]);
  }
}

void toRgba8(const TileImage& im, std::uint8_t* rgba) {
  const std::size_t n = static_cast<std::size_t>(im.width) * im.height;
  for (std::size_t i = 0; i < n; ++i) {
    const float* p = im.rgba.data() + 4 * i;
    const float a = p[3];
    for (int c = 0; c < 3; ++c) rgba[4 * i + c] = a > 0.0f ? toU8(p[c] / a) : 0;
    rgba[4 * i + 3] = toU8(a);
  }
}

}  // namespace pp5::pp
