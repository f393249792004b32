#pragma once
// The D-buffer (Ohbuchi & Fuchs 1991): for every pixel whose ray meets a
// changed region, the interval [t_in, t_out] of the ray inside it, so that
// only those lattice samples are taken again.
//
// Each box is scan-converted, not ray-tested: its faces are transformed to
// camera space, clipped against a near plane just in front of the eye (so a
// box partly behind the eye works), projected and rasterised with a
// pixel-centre rule; front faces give t_in and back faces t_out. Where a pixel
// sees a back face and no front face, its ray starts inside the box (an eye
// inside it, or the part in front was clipped), and t_in = 0. The per-pixel t
// is the exact ray-plane intersection along the pixel's own ray
// (PixelRays::ray), so it matches intersectBox() with the same ray.
//
// A pixel keeps the union of its boxes' intervals as up to kMaxSpans sorted,
// disjoint spans; when more would be needed, the two spans with the smallest
// gap between them are merged, which only adds samples (they are recomputed
// with the same values, so the cache is not harmed). Spans are floats rounded
// outwards. The touched pixels are listed, so later passes cost what the
// region covers, not the image.
//
// The fill rule: a polygon covers a pixel whose centre (x + 0.5, y + 0.5) has
// y in [ymin, ymax) and x in [xl(y), xr(y)); a shared edge is evaluated from
// its endpoints in a fixed order, so faces that share an edge neither overlap
// nor leave a gap. Pixels whose centre lies within rounding of a projected
// edge may fall on either side.
#include <cstdint>
#include <span>
#include <vector>

#include "core/camera.hpp"
#include "core/sample_lattice.hpp"
#include "reconstruction/world_box.hpp"

namespace pp5::gp {


class DBuffer {
public:
  static constexpr int kMaxSpans = 4;
  struct Span {
    float tIn, tOut;
  };
  struct Stats {
    std::uint64_t boxes = 0;
    std::uint64_t facePixels = 0;    // pixels written by rasterised faces
    std::uint64_t boxPixels = 0;     // (pixel, box) intervals produced
    std::uint64_t startsInside = 0;  // of those, back face without front face: t_in = 0
    std::uint64_t frontOnly = 0;     // front face without back face (rounding at an edge): ray-tested
    std::uint64_t spanMerges = 0;    // more than kMaxSpans spans: two merged
  };

  DBuffer() = default;
  explicit DBuffer(const Camera& camera) { reset(camera); }

  // Empty, for `camera`'s image; keeps the allocations of an earlier use.
  void reset(const Camera& camera);
  // Adds the box's interval to every pixel whose ray meets it at t >= 0.
  void addBox(const WorldBox& box);
  void addBoxes(std::span<const WorldBox> boxes) {
    for (const auto& b : boxes) addBox(b);
  }
  // Lists the touched pixels in ascending order: call once, after the last
  // addBox (it clears what addBox noted per row).
  void finish();
  // reset + addBoxes + finish.
  void build(const Camera& camera, std::span<const WorldBox> boxes);

  const PixelRays& rays() const { return rays_; }
  int width() const { return rays_.width(); }
  int height() const { return rays_.height(); }
  // Pixels with at least one span, ascending after finish().
  std::span<const std::uint32_t> touched() const { return touched_; }
  // A pixel's spans in ascending order; empty when the pixel is untouched.
  std::span<const Span> spans(std::uint32_t pixel) const {
    if (pixel >= slot_.size() || slot_[pixel] == kNone) return {};
    const Entry& e = entries_[slot_[pixel]];
    return {e.s, e.n};
  }
  const Stats& stats() const { return stats_; }
  // Perspective: the unit ray direction of a touched pixel, bitwise
  // rays().ray(pixel).dir (kept from addBox); nullptr for orthographic views.
  const Vec3* touchedDirs() const { return rays_.perspective() ? dirs_.data() : nullptr; }

private:
  static constexpr std::uint32_t kNone = 0xffffffffu;
  struct Entry {
    Span s[kMaxSpans];
    std::uint8_t n = 0;
  };

  PixelRays rays_;
  // Perspective: pixels' unit ray directions, kept while the camera stays (a
  // normalisation per pixel and box was a third of addBox's time). Filled on
  // demand, row by row: row y holds [dirsLo_[y], dirsHi_[y]), so the first
  // frame after a view change pays for its own pixels, not the image's.
  std::vector<Vec3> dirs_;
  std::vector<int> dirsLo_, dirsHi_;
  Camera dirsCamera_;
  const Vec3* rowDirs(int y, int x0, int x1);
  std::vector<std::uint32_t> slot_;  // per image pixel: index into entries_, or kNone
  std::vector<std::uint32_t> touched_;
  std::vector<int> rowLo_, rowHi_;  // per image row, the touched columns' range (lo > hi: none)
  std::vector<Entry> entries_;  // in the order the pixels were first touched
  std::vector<std::uint8_t> front_, back_;  // per box: which face covers each pixel of its bounds
  Stats stats_;

  void insert(std::uint32_t pixel, double tIn, double tOut);
};

}  // namespace pp5::gp
