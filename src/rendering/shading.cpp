#include "rendering/shading.hpp"

#include <omp.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <tuple>

#include "core/error.hpp"
#include "core/threads.hpp"

namespace pp5::gp {

namespace {

// Grey values are read in place from the volume's little-endian bytes and
// clamped to 0..255, so that no NaN or infinity a file may hold reaches a
// table index or an integer conversion.
inline float clampGrey(float x) {
  x = x > 0.0f ? x : 0.0f;  // also NaN
  return x < 255.0f ? x : 255.0f;
}

struct LoadF32 {
  static constexpr std::size_t kBytes = 4;
  static float at(const std::uint8_t* p) {
    std::uint32_t u;
    std::memcpy(&u, p, 4);
    if constexpr (std::endian::native == std::endian::big) u = __builtin_bswap32(u);
    return clampGrey(std::bit_cast<float>(u));
  }
};
struct LoadU16 {
  static constexpr std::size_t kBytes = 2;
  static float at(const std::uint8_t* p) {
    return clampGrey(static_cast<float>(static_cast<unsigned>(p[0]) | (static_cast<unsigned>(p[1]) << 8)));
  }
};
struct LoadU8 {
  static constexpr std::size_t kBytes = 1;
  static float at(const std::uint8_t* p) { return static_cast<float>(*p); }
};

// x^n on [0, 1], linearly interpolated from a table sized to n: the error of
// linear interpolation is at most h^2 n^2 / 8 for step h, so 16 n entries keep
// it under 5e-4, an eighth of one output level, at a cost of one table per
// call instead of one pow per voxel.
class PowTable {
public:
  PowTable() = default;
  explicit PowTable(double n) {
    const int size = std::clamp(static_cast<int>(std::ceil(16.0 * n)), 64, 4096);
    t_.resize(static_cast<std::size_t>(size) + 2);
    for (int i = 0; i <= size; ++i) t_[static_cast<std::size_t>(i)] = static_cast<float>(std::pow(double(i) / size, n));
    t_.back() = t_[static_cast<std::size_t>(size)];  // x = 1 reads one past the end of its interval
    scale_ = static_cast<float>(size);
  }
  float operator()(float x) const {  // x in [0, 1]
    const float u = std::min(x, 1.0f) * scale_;
    const auto i = static_cast<std::size_t>(u);
    const float f = u - static_cast<float>(i);
    return t_[i] + f * (t_[i + 1] - t_[i]);
  }

private:
  std::vector<float> t_;
  float scale_ = 1.0f;
};

// Where the light comes from, fixed per call so that the voxel loop holds no
// test of it. Fixed: L and H are the same for every voxel (a directional light
// or a headlight seen orthographically). Headlight: L = H = the direction to
// the eye, per voxel. Directional: L fixed, H from the per-voxel view.
enum class Lighting { None, Fixed, Headlight, Directional };

struct Context {
  const TransferFunction* tf = nullptr;
  const std::uint8_t* vol = nullptr;
  ShadeVoxel* out = nullptr;
  std::int64_t nx = 0, ny = 0, nz = 0;
  glm::vec3 spacing{1.0f};
  glm::vec3 oneSided{1.0f}, central{0.5f};  // 1 / spacing, 0.5 / spacing
  float ka = 0, kd = 0, ks = 0;
  float invFlat = 1.0f;
  float goLow = 0.0f, goInvWidth = 1.0f;
  glm::vec3 L{0.0f}, H{0.0f};  // unit, towards the light / half vector (Fixed)
  glm::vec3 eyeRel{0.0f};      // eye - origin, mm
  PowTable spec;  // phong only
  bool greyColour = false;  // grey mode: colour = grey level / 255
  std::int64_t valueBytes = 4;
  bool rowsAhead = true;  // shadeRow fetches the row 4 on (false: shadeBoxes fetches the next pieces' rows)
};

// Asks for the lines that shading row (j, k) of `x` reads (its values and
// the four face-neighbour rows', a voxel on from either end) and writes: a
// change's rows are a grid row or plane apart, which the hardware does not
// fetch ahead.
void prefetchRow(const Context& c, const Box3& x, std::int64_t j, std::int64_t k) {
  const std::int64_t i0 = std::max<std::int64_t>(x.lo.x - 1, 0), i1 = std::min<std::int64_t>(x.hi.x, c.nx - 1);
  const std::int64_t B = c.valueBytes;
  auto fetch = [&](std::int64_t j, std::int64_t k) {
    if (j < 0 || j >= c.ny || k < 0 || k >= c.nz) return;
    const std::uint8_t* row = c.vol + (k * c.ny + j) * c.nx * B;
    for (std::int64_t o = i0 * B; o <= i1 * B + 63; o += 64) __builtin_prefetch(row + std::min(o, i1 * B), 0, 3);
  };
  fetch(j, k);
  fetch(j - 1, k);
  fetch(j + 1, k);
  fetch(j, k - 1);
  fetch(j, k + 1);
  const ShadeVoxel* out = c.out + (k * c.ny + j) * c.nx;
  for (std::int64_t i = x.lo.x; i < x.hi.x + 16; i += 16) __builtin_prefetch(out + std::min(i, x.hi.x - 1), 1, 3);
}

inline std::uint8_t quantise(float x) { return static_cast<std::uint8_t>(x + 0.5f); }  // x in [0, 255]

// Straight colour (any non-negative intensity) and opacity to premultiplied
// RGBA8. Each colour component is clamped to 1 before it is scaled by the same
// a255 that gives the opacity, so rounding keeps r, g, b <= a.
inline ShadeVoxel pack(float r, float g, float b, float a) {
  a = std::min(std::max(a, 0.0f), 1.0f);
  const float a255 = a * 255.0f;
  ShadeVoxel o;
  o.a = quantise(a255);
  o.r = quantise(std::min(r, 1.0f) * a255);
  o.g = quantise(std::min(g, 1.0f) * a255);
  o.b = quantise(std::min(b, 1.0f) * a255);
  return o;
}

// A row is shaded in runs of up to kRun voxels, one pass per step over plain
// arrays. Classification comes first, and only the voxels it leaves visible
// are gathered (without a branch) for the gradient and the light: a
// transparent voxel is transparent whatever its normal, and in ultrasound
// most of the grid is transparent water or speckle below the opacity ramp.
// Every pass does the same IEEE operations on a voxel wherever its run
// starts, so its bits do not depend on the box or the thread.
constexpr int kRun = 128;
// Added to a length before dividing by it, so that a zero vector gives a
// zero unit vector without a branch; far too small to change any length a
// gradient or a distance in mm can have.
constexpr float kTiny = 1e-30f;

struct RunBuffers {
  float v[kRun];
  std::int32_t idx[kRun];  // the visible voxels' offsets in the run
  float r[kRun], g[kRun], b[kRun], a[kRun];
  float gx[kRun], gy[kRun], gz[kRun];
  float intensity[kRun], highlight[kRun], nh[kRun];
};

// Voxels x0 <= i < x1 of row (j, k).
template <class Load, Lighting K, bool GradOpacity>
void shadeRow(const Context& c, std::int64_t j, std::int64_t k, std::int64_t x0, std::int64_t x1) {
  constexpr bool kGradient = K != Lighting::None || GradOpacity;
  constexpr auto B = static_cast<std::int64_t>(Load::kBytes);
  const std::int64_t nx = c.nx;
  auto row = [&](std::int64_t jj, std::int64_t kk) { return c.vol + ((kk * c.ny + jj) * nx) * B; };
  auto at = [](const std::uint8_t* r, std::int64_t i) { return Load::at(r + i * B); };
  const std::uint8_t* const r0 = row(j, k);
  ShadeVoxel* const outRow = c.out + (k * c.ny + j) * nx;

  // Central differences inside the grid, one-sided on its faces, none
  // across an axis one voxel long: the factor is indexed by the distance
  // between the two neighbours read (0, 1 or 2 voxels).
  const std::int64_t jm = std::max<std::int64_t>(j - 1, 0), jp = std::min(j + 1, c.ny - 1);
  const std::int64_t km = std::max<std::int64_t>(k - 1, 0), kp = std::min(k + 1, c.nz - 1);
  const float fy = jp - jm == 2 ? c.central.y : jp - jm == 1 ? c.oneSided.y : 0.0f;
  const float fz = kp - km == 2 ? c.central.z : kp - km == 1 ? c.oneSided.z : 0.0f;
  const float fx[3] = {0.0f, c.oneSided.x, c.central.x};
  const std::uint8_t *const rym = row(jm, k), *const ryp = row(jp, k), *const rzm = row(j, km),
                     *const rzp = row(j, kp);
  if (x1 > x0 && c.rowsAhead) {
    // Rows run along x: in a slab thin in x each row is a few cache lines a
    // kilobyte or more from the last, which the hardware does not fetch ahead.
    // Fetch the row four ahead (the next rows of a box are j + 1, j + 2, ...).
    const std::int64_t ja = std::min(j + 4, c.ny - 1);
    const std::uint8_t* const ahead = row(ja, k) + x0 * B;
    ShadeVoxel* const aheadOut = c.out + (k * c.ny + ja) * nx + x0;
    const std::int64_t bytes = (x1 - x0) * B, outBytes = (x1 - x0) * static_cast<std::int64_t>(sizeof(ShadeVoxel));
    for (std::int64_t o = 0; o < bytes + 63; o += 64) __builtin_prefetch(ahead + std::min(o, bytes - 1), 0, 3);
    for (std::int64_t o = 0; o < outBytes + 63; o += 64)
      __builtin_prefetch(reinterpret_cast<const std::uint8_t*>(aheadOut) + std::min(o, outBytes - 1), 1, 3);
  }
  const float ey = c.eyeRel.y - static_cast<float>(j) * c.spacing.y;
  const float ez = c.eyeRel.z - static_cast<float>(k) * c.spacing.z;
  const float eyz2 = ey * ey + ez * ez;

  RunBuffers buf;
  for (std::int64_t s = x0; s < x1; s += kRun) {
    const int n = static_cast<int>(std::min(x1, s + kRun) - s);
    ShadeVoxel* const out = outRow + s;

    for (int q = 0; q < n; ++q) buf.v[q] = at(r0, s + q);
    float vmax = 0.0f;  // a pass of its own: it vectorises, and folded into the loads it was slower
    for (int q = 0; q < n; ++q) vmax = std::max(vmax, buf.v[q]);
    if (c.tf->transparentUpTo(vmax)) {  // below the opacity ramp: what the lookups would give
      std::fill_n(out, n, ShadeVoxel{});
      continue;
    }
    int visible = 0;
    for (int q = 0; q < n; ++q) {
      const Rgba t = (*c.tf)(buf.v[q]);
      buf.idx[visible] = q;
      buf.r[visible] = t.r;
      buf.g[visible] = t.g;
      buf.b[visible] = t.b;
      buf.a[visible] = t.a;
      visible += t.a > 0.0f;
    }
    std::fill_n(out, n, ShadeVoxel{});
    const int m = visible;
    if (c.greyColour)  // grey mode: the image value as the colour (a pass of its own, off the table loop)
      for (int p = 0; p < m; ++p) buf.r[p] = buf.g[p] = buf.b[p] = buf.v[buf.idx[p]] * (1.0f / 255.0f);

    if constexpr (kGradient) {
      for (int p = 0; p < m; ++p) {
        const std::int64_t i = s + buf.idx[p];
        const std::int64_t im = std::max<std::int64_t>(i - 1, 0), ip = std::min(i + 1, nx - 1);
        buf.gx[p] = (at(r0, ip) - at(r0, im)) * fx[ip - im];
        buf.gy[p] = (at(ryp, i) - at(rym, i)) * fy;
        buf.gz[p] = (at(rzp, i) - at(rzm, i)) * fz;
      }
      for (int p = 0; p < m; ++p) {
        const float gx = buf.gx[p], gy = buf.gy[p], gz = buf.gz[p];
        const float len = std::sqrt(gx * gx + gy * gy + gz * gz);
        if constexpr (GradOpacity) buf.a[p] *= std::min(std::max((len - c.goLow) * c.goInvWidth, 0.0f), 1.0f);
        if constexpr (K != Lighting::None) {
          const float inv = 1.0f / (len + kTiny);
          const float nX = gx * inv, nY = gy * inv, nZ = gz * inv;
          float nl, nh;
          if constexpr (K == Lighting::Fixed) {
            nl = nX * c.L.x + nY * c.L.y + nZ * c.L.z;
            nh = nX * c.H.x + nY * c.H.y + nZ * c.H.z;
          } else {
            const float ex = c.eyeRel.x - static_cast<float>(s + buf.idx[p]) * c.spacing.x;
            const float ie = 1.0f / (std::sqrt(ex * ex + eyz2) + kTiny);
            const float vx = ex * ie, vy = ey * ie, vz = ez * ie;  // unit, towards the eye
            if constexpr (K == Lighting::Headlight) {
              nl = nX * vx + nY * vy + nZ * vz;
              nh = nl;
            } else {
              const float hx = c.L.x + vx, hy = c.L.y + vy, hz = c.L.z + vz;
              const float ih = 1.0f / (std::sqrt(hx * hx + hy * hy + hz * hz) + kTiny);
              nl = nX * c.L.x + nY * c.L.y + nZ * c.L.z;
              nh = (nX * hx + nY * hy + nZ * hz) * ih;
            }
          }
          // Two-sided: the normal turned towards the light.
          nh = std::copysign(1.0f, nl) * nh;
          const float w = std::min(len * c.invFlat, 1.0f);
          buf.intensity[p] = c.ka + c.kd * (1.0f + w * (std::abs(nl) - 1.0f));
          buf.highlight[p] = c.ks * w;
          buf.nh[p] = std::min(std::max(nh, 0.0f), 1.0f);
        }
      }
    }
    if constexpr (K != Lighting::None) {
      for (int p = 0; p < m; ++p) buf.highlight[p] *= c.spec(buf.nh[p]);
      for (int p = 0; p < m; ++p) {
        const float I = buf.intensity[p], h = buf.highlight[p];
        out[buf.idx[p]] = pack(buf.r[p] * I + h, buf.g[p] * I + h, buf.b[p] * I + h, buf.a[p]);
      }
    } else {
      for (int p = 0; p < m; ++p) out[buf.idx[p]] = pack(buf.r[p], buf.g[p], buf.b[p], buf.a[p]);
    }
  }
}

using RowFn = void (*)(const Context&, std::int64_t, std::int64_t, std::int64_t, std::int64_t);

// greyValues: each voxel its own grey level as colour and opacity, unlit and
// unclassified (what MIP and additive composite).
template <class Load>
void greyRow(const Context& c, std::int64_t j, std::int64_t k, std::int64_t x0, std::int64_t x1) {
  constexpr auto B = static_cast<std::int64_t>(Load::kBytes);
  const std::uint8_t* const r0 = c.vol + ((k * c.ny + j) * c.nx) * B;
  ShadeVoxel* const out = c.out + (k * c.ny + j) * c.nx;
  for (std::int64_t i = x0; i < x1; ++i) {
    const auto v = static_cast<std::uint8_t>(std::lround(Load::at(r0 + i * B)));
    out[i] = ShadeVoxel{v, v, v, v};
  }
}

template <class Load, bool GradOpacity>
RowFn pickLighting(Lighting k) {
  switch (k) {
    case Lighting::None: return &shadeRow<Load, Lighting::None, GradOpacity>;
    case Lighting::Fixed: return &shadeRow<Load, Lighting::Fixed, GradOpacity>;
    case Lighting::Headlight: return &shadeRow<Load, Lighting::Headlight, GradOpacity>;
    case Lighting::Directional: return &shadeRow<Load, Lighting::Directional, GradOpacity>;
  }
  return nullptr;
}

template <class Load>
RowFn pickRow(Lighting k, bool gradOpacity) {
  return gradOpacity ? pickLighting<Load, true>(k) : pickLighting<Load, false>(k);
}

// A run of rows of one box: the unit of work handed to a thread.
struct Work {
  std::uint32_t box;
  std::int64_t rowBegin, rowEnd;  // rows of the box, row = (k - lo.z) * height + (j - lo.y)
};

// Every voxel of `boxes` (disjoint, inside the grid). Rows are grouped into
// pieces of about kPieceVoxels so that small boxes are not split across
// threads and large ones are; the split never changes a voxel's value.
void shadeBoxes(const Context& context, RowFn fn, const std::vector<Box3>& boxes, int threads,
                std::vector<std::int64_t>* changed) {
  constexpr std::int64_t kPieceVoxels = 8192;
  std::vector<Work> work;
  std::uint64_t total = 0;
  // Boxes one row tall (the runs of an update) are pieces of one row, whose
  // rows the loop below fetches ahead: shadeRow's own fetch of the row 4 on
  // in the same box would be of a row that is not shaded.
  Context c = context;
  c.rowsAhead = std::any_of(boxes.begin(), boxes.end(), [](const Box3& x) {
    return x.hi.y - x.lo.y > 1 || x.hi.z - x.lo.z > 1;
  });
  for (std::size_t b = 0; b < boxes.size(); ++b) {
    const Box3& x = boxes[b];
    if (x.empty()) continue;
    const std::int64_t width = x.hi.x - x.lo.x, rows = (x.hi.y - x.lo.y) * (x.hi.z - x.lo.z);
    const std::int64_t per = std::max<std::int64_t>(1, kPieceVoxels / width);
    for (std::int64_t r = 0; r < rows; r += per) work.push_back({static_cast<std::uint32_t>(b), r, std::min(rows, r + per)});
    total += x.voxelCount();
  }
  const auto n = static_cast<std::int64_t>(work.size());
  // Starting a team costs more than a few thousand voxels take.
  const bool parallel = threads > 1 && n > 1 && total >= 2 * static_cast<std::uint64_t>(kPieceVoxels);
  const int team = parallel ? threads : 1;
  // With `changed`: each thread lists the voxels whose shade it changed,
  // comparing a row's old shades (kept in `before`) with its new ones.
  std::vector<std::vector<std::int64_t>> found(changed ? static_cast<std::size_t>(team) : 0);
#pragma omp parallel num_threads(team) if (parallel)
  {
    std::vector<ShadeVoxel> before;
    std::vector<std::int64_t>* mine = changed ? &found[static_cast<std::size_t>(omp_get_thread_num())] : nullptr;
#pragma omp for schedule(dynamic, 1)
    for (std::int64_t w = 0; w < n; ++w) {
      constexpr std::int64_t kAhead = 4;  // pieces fetched ahead (one-row boxes: the runs of an update)
      if (w + kAhead < n) {
        const Work& ahead = work[static_cast<std::size_t>(w + kAhead)];
        const Box3& x = boxes[ahead.box];
        const std::int64_t height = x.hi.y - x.lo.y;
        prefetchRow(c, x, x.lo.y + ahead.rowBegin % height, x.lo.z + ahead.rowBegin / height);
      }
      const Work& wk = work[static_cast<std::size_t>(w)];
      const Box3& x = boxes[wk.box];
      const std::int64_t height = x.hi.y - x.lo.y;
      for (std::int64_t r = wk.rowBegin; r < wk.rowEnd; ++r) {
        const std::int64_t j = x.lo.y + r % height, k = x.lo.z + r / height;
        if (!mine) {
          fn(c, j, k, x.lo.x, x.hi.x);
          continue;
        }
        const std::int64_t first = (k * c.ny + j) * c.nx + x.lo.x, len = x.hi.x - x.lo.x;
        before.assign(c.out + first, c.out + first + len);
        fn(c, j, k, x.lo.x, x.hi.x);
        for (std::int64_t i = 0; i < len; ++i)
          if (!(before[static_cast<std::size_t>(i)] == c.out[first + i])) mine->push_back(first + i);
      }
    }
  }
  if (changed)
    for (const auto& f : found) changed->insert(changed->end(), f.begin(), f.end());
}

void shadeAll(const Volume& values, const TransferFunction& tf, const ShadeSettings& s, const Camera& view,
              const std::vector<Box3>& boxes, ShadeBuffer& out, std::vector<std::int64_t>* changed = nullptr) {
  const Grid& g = values.grid;
  PP5_CHECK(g.dims == out.grid().dims);
  PP5_CHECK_EQ(values.bytes.size(), g.voxelCount() * static_cast<std::uint64_t>(scalarBytes(values.type)));
  // Settings built in code are held to the names a file could give.
  const ShadeMode mode = checkedEnum(s.mode);
  const LightKind light = checkedEnum(s.light);
  checkShadeSettings(s);

  Context c;
  c.tf = &tf;
  c.vol = values.bytes.data();
  c.out = out.data();
  c.nx = g.dims.x;
  c.ny = g.dims.y;
  c.nz = g.dims.z;
  c.spacing = glm::vec3(g.spacing);
  c.oneSided = glm::vec3(1.0 / g.spacing);
  c.central = glm::vec3(0.5 / g.spacing);
  c.ka = static_cast<float>(s.ambient);
  c.kd = static_cast<float>(s.diffuse);
  c.ks = static_cast<float>(s.specular);
  c.invFlat = static_cast<float>(1.0 / std::max(s.flatGradient, 1e-12));
  c.goLow = static_cast<float>(s.gradientOpacityLow);
  c.goInvWidth = static_cast<float>(1.0 / std::max(s.gradientOpacityWidth, 1e-12));
  c.eyeRel = glm::vec3(view.eye - g.origin);
  c.greyColour = mode == ShadeMode::Grey;
  c.valueBytes = scalarBytes(values.type);

  Lighting k = Lighting::None;
  if (mode == ShadeMode::Phong) {
    c.spec = PowTable(s.shininess);
    const bool ortho = view.projection == Projection::Orthographic;
    const Vec3 toViewer = -view.forward();
    // A camera whose eye is on its target, or not finite, has no view direction.
    PP5_CHECK(std::isfinite(toViewer.x + toViewer.y + toViewer.z + view.eye.x + view.eye.y + view.eye.z));
    if (light == LightKind::Viewer) {
      k = ortho ? Lighting::Fixed : Lighting::Headlight;
      c.L = c.H = glm::vec3(toViewer);
    } else {
      const Vec3 toLight = -glm::normalize(s.lightDirection);
      c.L = glm::vec3(toLight);
      k = ortho ? Lighting::Fixed : Lighting::Directional;
      const Vec3 h = toLight + toViewer;
      c.H = glm::length(h) > 1e-12 ? glm::vec3(glm::normalize(h)) : glm::vec3(0.0f);
    }
  }

  RowFn fn = nullptr;
  switch (values.type) {
    case ScalarType::F32: fn = s.greyValues ? &greyRow<LoadF32> : pickRow<LoadF32>(k, s.gradientOpacity); break;
    case ScalarType::U16: fn = s.greyValues ? &greyRow<LoadU16> : pickRow<LoadU16>(k, s.gradientOpacity); break;
    case ScalarType::U8: fn = s.greyValues ? &greyRow<LoadU8> : pickRow<LoadU8>(k, s.gradientOpacity); break;
  }
  PP5_CHECK(fn != nullptr);
  const int threads = resolveThreads(s.threads);
  shadeBoxes(c, fn, boxes, threads, changed);
}

// Merges boxes that share their extent on the two other axes and touch along
// `axis`; the boxes stay disjoint and cover the same voxels.
void mergeAlong(std::vector<Box3>& boxes, int axis) {
  const int a = axis, b = (axis + 1) % 3, d = (axis + 2) % 3;
  auto key = [&](const Box3& x) { return std::make_tuple(x.lo[b], x.hi[b], x.lo[d], x.hi[d], x.lo[a]); };
  std::sort(boxes.begin(), boxes.end(), [&](const Box3& x, const Box3& y) { return key(x) < key(y); });
  std::vector<Box3> merged;
  merged.reserve(boxes.size());
  for (const Box3& x : boxes) {
    if (!merged.empty()) {
      Box3& m = merged.back();
      if (m.lo[b] == x.lo[b] && m.hi[b] == x.hi[b] && m.lo[d] == x.lo[d] && m.hi[d] == x.hi[d] && m.hi[a] == x.lo[a]) {
        m.hi[a] = x.hi[a];
        continue;
      }
    }
    merged.push_back(x);
  }
  boxes.swap(merged);
}

}  // namespace

std::vector<Box3> shadingBoxes(const DirtyRegion& dirty) {
  std::vector<Box3> boxes;
  if (dirty.empty()) return boxes;
  const Index3 bd = dirty.brickDims();
  const std::vector<std::uint32_t>& bricks = dirty.bricks();
  auto id = [&](const Index3& b) { return static_cast<std::uint32_t>((b.z * bd.y + b.y) * bd.x + b.x); };
  auto coords = [&](std::uint32_t i) {
    const std::int64_t l = i;
    return Index3(l % bd.x, (l / bd.x) % bd.y, l / (bd.x * bd.y));
  };
  auto inside = [&](const Index3& b) { return b.x >= 0 && b.y >= 0 && b.z >= 0 && b.x < bd.x && b.y < bd.y && b.z < bd.z; };
  // A byte per brick of the grid (a frame dirties a thousand bricks or more,
  // each asked about its six neighbours).
  std::vector<std::uint8_t> dirtyMap(static_cast<std::size_t>(bd.x * bd.y * bd.z), 0);
  for (const std::uint32_t d : bricks) dirtyMap[d] = 1;
  auto isDirty = [&](const Index3& b) { return inside(b) && dirtyMap[id(b)] != 0; };

  // The clean bricks that share a face with a dirty one.
  std::vector<std::uint32_t> clean;
  for (const std::uint32_t d : bricks) {
    boxes.push_back(dirty.brickBox(d));
    const Index3 b = coords(d);
    for (int a = 0; a < 3; ++a)
      for (const int sgn : {-1, 1}) {
        Index3 n = b;
        n[a] += sgn;
        if (inside(n) && !isDirty(n)) clean.push_back(id(n));
      }
  }
  std::sort(clean.begin(), clean.end());
  clean.erase(std::unique(clean.begin(), clean.end()), clean.end());

  // Of a clean brick, the voxel layers on its faces towards dirty bricks.
  // Layers along x span the brick; those along y leave out the x layers
  // already taken, and those along z both, so the pieces are disjoint. A brick
  // one voxel thick along an axis has one layer there, taken once.
  for (const std::uint32_t c : clean) {
    const Box3 cell = dirty.brickBox(c);
    const Index3 b = coords(c);
    Index3 lo = cell.lo, hi = cell.hi;  // what the layers taken so far leave
    for (int a = 0; a < 3; ++a) {
      Index3 e(0);
      e[a] = 1;
      if (isDirty(b - e) && lo[a] < hi[a]) {
        Box3 layer{lo, hi};
        layer.hi[a] = cell.lo[a] + 1;
        if (!layer.empty()) boxes.push_back(layer);
        lo[a] = cell.lo[a] + 1;
      }
      if (isDirty(b + e) && lo[a] < hi[a]) {
        Box3 layer{lo, hi};
        layer.lo[a] = cell.hi[a] - 1;
        if (!layer.empty()) boxes.push_back(layer);
        hi[a] = cell.hi[a] - 1;
      }
    }
  }
  mergeAlong(boxes, 0);
  mergeAlong(boxes, 1);
  mergeAlong(boxes, 2);
  return boxes;
}

void shade(const Volume& values, const TransferFunction& tf, const ShadeSettings& s, const Camera& view,
           const Box3& box, ShadeBuffer& out) {
  shade(values, tf, s, view, std::span<const Box3>(&box, 1), out);
}

void shade(const Volume& values, const TransferFunction& tf, const ShadeSettings& s, const Camera& view,
           std::span<const Box3> boxes, ShadeBuffer& out, std::vector<std::int64_t>* changed) {
  std::vector<Box3> clipped;
  clipped.reserve(boxes.size());
  for (const Box3& b : boxes) {
    const Box3 c = b.intersect({Index3(0), values.grid.dims});
    if (!c.empty()) clipped.push_back(c);
  }
  const std::size_t had = changed ? changed->size() : 0;
  shadeAll(values, tf, s, view, clipped, out, changed);
  // One thread lists the voxels in the boxes' order, for runs ascending already.
  const auto from = changed ? changed->begin() + static_cast<std::ptrdiff_t>(had) : std::vector<std::int64_t>::iterator{};
  if (changed && !std::is_sorted(from, changed->end())) std::sort(from, changed->end());
}

void shade(const Volume& values, const TransferFunction& tf, const ShadeSettings& s, const Camera& view,
           const DirtyRegion& dirty, ShadeBuffer& out) {
  PP5_CHECK(dirty.grid().dims == values.grid.dims);
  shadeAll(values, tf, s, view, shadingBoxes(dirty), out);
}

}  // namespace pp5::gp
