#include "reconstruction/slice_geometry.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::gp {

// ------------------------------------------------------------------ poses --

SlicePose poseFromMatrix(const Mat4& m, const std::string& what) {
  if (!isFinite(m)) throw InputError(what + ": the image-to-reference transform is not finite");
  // glm is column-major: m[col][row]; the last row must be (0 0 0 1).
  const double tol = 1e-9;
  if (std::abs(m[0][3]) > tol || std::abs(m[1][3]) > tol || std::abs(m[2][3]) > tol || std::abs(m[3][3] - 1.0) > tol)
    throw InputError(what + ": the image-to-reference transform is not affine (last row is not 0 0 0 1)");
  const Vec3 ex(m[0]), ey(m[1]);
  SlicePose p;
  p.origin = Vec3(m[3]);
  p.ex = ex;
  p.ey = ey;
  p.sx = glm::length(ex);
  const Vec3 c = glm::cross(ex, ey);
  const double cl = glm::length(c);
  if (!(p.sx > 1e-12) || !(glm::length(ey) > 1e-12) || !(cl > 1e-12 * p.sx * glm::length(ey)))
    throw InputError(what + ": the image-to-reference transform maps the image's x and y axes onto a line or a point");
  p.u = ex / p.sx;
  p.n = c / cl;
  p.v = glm::cross(p.n, p.u);
  p.eyu = glm::dot(ey, p.u);
  p.syv = glm::dot(ey, p.v);
  p.q = glm::normalize(glm::quat_cast(glm::dmat3(p.u, p.v, p.n)));
  return p;
}

// Rotation angle between two slices' orientations, radians.
double rotationAngle(const SlicePose& a, const SlicePose& b) {
  const double d = std::min(1.0, std::abs(glm::dot(a.q, b.q)));
  return 2.0 * std::acos(d);
}

// Translation of the image origin (pixel (0,0), on the transducer face for
// MF images, so a rocking sweep about the face interpolates without cutting
// chords) linear; rotation by slerp (the short way); pixel steps linear.
SlicePose interpolatePose(const SlicePose& a, const SlicePose& b, double t) {
  SlicePose p;
  p.origin = a.origin + (b.origin - a.origin) * t;
  const Quat qb = glm::dot(a.q, b.q) < 0.0 ? -b.q : b.q;
  p.q = glm::normalize(glm::slerp(a.q, qb, t));
  const glm::dmat3 r = glm::mat3_cast(p.q);
  p.u = r[0];
  p.v = r[1];
  p.n = r[2];
  p.sx = a.sx + (b.sx - a.sx) * t;
  p.eyu = a.eyu + (b.eyu - a.eyu) * t;
  p.syv = a.syv + (b.syv - a.syv) * t;
  return p;
}

// ---------------------------------------------------------------- fill-in --
//
// Between two consecutive frames whose pixel rectangles' corners moved by up
// to D mm, n = ceil(D / s_max) - 1 intermediate slices are splatted at
// t = k/(n+1), so consecutive slices are at most s_max = he (the elevation
// half-width) apart everywhere on the image (the displacement of an image
// point is affine in the pixel position, so it is largest at a corner).
//
// Why he: tent kernels of half-width he placed every he along the normal sum
// to exactly 1 at every point between them (the linear-interpolation hat
// functions form a partition of unity). So with spacing <= he every point
// between two slices is reached by both of them and is at most he/2 from the
// nearer one (weight >= 1/2 from it): no holes, and the elevational weight is
// even, with no ridges at the slices. A spacing between he and 2*he would
// still reach every point, but the midplanes only with weights that fall to 0
// as the spacing nears 2*he, and the total weight would ripple with the slice
// positions (coarse holes in all but name); anything finer than
// he only adds work, since at spacing he each point is already the linear
// interpolation of its two bracketing slices. Fill-in starts exactly when
// D > he. For a 1.5 mm half-width, frames 2 mm apart get one intermediate
// slice (1 mm spacing; the default 3 mm needs none); the paper interpolated
// about 3 points between slices 2 mm apart (0.5 mm spacing), which this rule
// gives for a 0.5 mm elevation half-width: the density follows the kernel
// rather than being fixed.
int fillInCount(double maxCornerDisplacementMm, double elevationHalfWidthMm) {
  if (!(maxCornerDisplacementMm > elevationHalfWidthMm)) return 0;
  return static_cast<int>(std::ceil(maxCornerDisplacementMm / elevationHalfWidthMm)) - 1;
}

// ------------------------------------------------------------------ reach --
//
// What the tent splat writes (reconstruction/splat_tent.cpp): a slice at pose (origin,
// image axes ex, ey) writes a voxel only when some selected pixel's kernel
// reaches it with a positive weight, i.e. when the voxel lies strictly inside
// pixel + (du u + dv v + dn n) with |du| < hl, |dv| < ha, |dn| < he, where u =
// ex / |ex|, n = ex x ey normalised and v = n x u (SlicePose). Its writes thus
// lie in the Minkowski sum of the selected pixel centres' parallelogram and
// the kernel's oriented box, whose world box is the sum of the two world
// boxes: the parallelogram's corners, and per axis a half-extent hl |u_a| +
// ha |v_a| + he |n_a|. That is the exact hull of the written set (for a
// sheared image it is tighter than the splat's own dirty slab, which bounds
// the pixels by their (u, v) rectangle); kPadMm (as the splat's own dirty
// region adds) and a relative term cover the rounding of the splat's float
// weights and of the arithmetic here.
//
// The selected pixels lie inside the clip rectangle (the fan and rejected
// pixels only remove some), so the rectangle stands for them; a rectangle that
// misses the frame selects nothing, and the splat then takes the whole frame
// for its geometry, as this does.
//
// Other methods than tent do not call these (their callers use the dirty
// region); the functions return the same box for them, built from the tent
// half-widths in `recon`, whatever the method.
//
// The box holds the voxels whose sums a slice changes. With replacement =
// motion_vector a slice also rebases every motion-vector cell it writes to
// (motionVectorBrick voxels a side, aligned to the grid's voxel 0): their
// outputs stay, but their bases and sums change, up to motionVectorBrick - 1
// voxels beyond the box. The box cannot see the grid, so a caller that must
// keep those states exact grows it by that many voxels.
namespace {

constexpr double kPadMm = 1e-3;
constexpr double kRelPad = 1e-9;

// The clip rectangle's pixel centres, inclusive, as pixelRuns clamps it.
struct PixelRect {
  double x0, y0, x1, y1;
};

PixelRect clipRect(int width, int height, const ReconSettings& s) {
  if (width < 1 || height < 1)
    throw InputError(fmt::format("a frame of {}x{} pixels has no pixels to reconstruct", width, height));
  std::int64_t x0 = 0, x1 = width - 1, y0 = 0, y1 = height - 1;
  if (s.clipSize.x > 0 && s.clipSize.y > 0) {
    const std::int64_t cx0 = std::max<std::int64_t>(x0, s.clipOrigin.x);
    const std::int64_t cy0 = std::max<std::int64_t>(y0, s.clipOrigin.y);
    const std::int64_t cx1 = std::min<std::int64_t>(x1, std::int64_t{s.clipOrigin.x} + s.clipSize.x);
    const std::int64_t cy1 = std::min<std::int64_t>(y1, std::int64_t{s.clipOrigin.y} + s.clipSize.y);
    if (cx0 <= cx1 && cy0 <= cy1) {
      x0 = cx0;
      y0 = cy0;
      x1 = cx1;
      y1 = cy1;
    }
  }
  return {static_cast<double>(x0), static_cast<double>(y0), static_cast<double>(x1), static_cast<double>(y1)};
}

std::array<std::array<double, 2>, 4> corners(const PixelRect& r) {
  return {{{r.x0, r.y0}, {r.x1, r.y0}, {r.x0, r.y1}, {r.x1, r.y1}}};
}

WorldBox padded(WorldBox b) {
  for (int a = 0; a < 3; ++a) {
    const double pad = kPadMm + kRelPad * std::max(std::abs(b.lo[a]), std::abs(b.hi[a]));
    b.lo[a] -= pad;
    b.hi[a] += pad;
  }
  return b;
}

// The box around the clipped rectangle's corners (`at` maps a pixel corner to
// world), grown per world axis by the tent kernel along the slice axes u, v, n.
template <typename At>
WorldBox kernelBox(const PixelRect& r, const ReconSettings& s, const Vec3& u, const Vec3& v, const Vec3& n,
                       At at) {
  WorldBox b{Vec3(std::numeric_limits<double>::infinity()), Vec3(-std::numeric_limits<double>::infinity())};
  for (const auto& [c, y] : corners(r)) {
    const Vec3 w = at(c, y);
    b.lo = glm::min(b.lo, w);
    b.hi = glm::max(b.hi, w);
  }
  const Vec3 k = s.tent.kernelLateralMm * glm::abs(u) + s.tent.kernelAxialMm * glm::abs(v) + s.tent.kernelElevationMm * glm::abs(n);
  b.lo -= k;
  b.hi += k;
  return b;
}

// The exact reach, unpadded.
WorldBox reachOf(const SlicePose& p, const PixelRect& r, const ReconSettings& s) {
  return kernelBox(r, s, p.u, p.v, p.n, [&](double c, double y) { return p.origin + c * p.ex + y * p.ey; });
}

}  // namespace

WorldBox frameReach(const Mat4& imageToReference, int width, int height, const ReconSettings& recon) {
  return padded(reachOf(poseFromMatrix(imageToReference, "the frame"), clipRect(width, height, recon), recon));
}

// The fill-in slices (reconstruction/splat_tent.cpp, interpolatePose) between poses a
// and b: at t in (0, 1), origin o(t) = lerp(o_a, o_b, t), rotation R(t) =
// R_a E(t theta), E the rotation by the angle theta between the frames about
// a fixed axis w (in a's axes), and pixel steps (sx, eyu, syv) linear in t.
// The reconstructor picks their number and t from the pixels it selects,
// which this cannot know, so the box holds the slices for every t.
//
// It is the union of the reaches of the slices at t_j = j / N (t_0 and t_N the
// frames themselves), N = ceil(theta / 1 degree), grown by what the path can
// bulge between two of them. Between t_j and t_j+1 the path is again of this
// form (origin linear, a slerp by theta / N about w, steps linear), so a point
// the slice at t writes is o(t) + R(t) p(t), with p(t) = lerp(p_j, p_j+1, s) + k
// in slice coordinates (a pixel, moved linearly, plus a kernel offset k), and
//     o(t) + R(t) p(t) = lerp(o_j + R_j p_j', o_j+1 + R_j+1 p_j+1', s)
//                        + (1 - s) d_j + s d_j+1 + s (1 - s) (R_j+1 - R_j)(p_j' - p_j+1'),
// with p' = p + k and d = R(t) p' - lerp(R_j p', R_j+1 p', s) the gap between
// the arc that p' sweeps at constant angular speed and its chord at the same
// s. The first term is a convex combination of points of the two slices'
// reaches, so it lies in the union's box. On a circle of radius rho and
// half-angle a = theta / (2N) the gap is at most rho (1 - cos a) across the
// chord (the sagitta) plus rho (a - sin a) along it; and |(R_j+1 - R_j) x| <=
// 2 sin(a) |x|, where |p_j - p_j+1| <= dMax / N. Every term is perpendicular to
// w, so along world axis i the growth is their sum times sqrt(1 - w_i^2). rho
// is the largest distance from the axis over the vertices of either frame's
// pixel rectangle plus kernel box: the distance is convex in p, and p(t) is
// linear in t. With 1 degree steps the growth is below 4e-5 rho (5 um for a
// 120 mm deep image), where growing the two frames' union once by the whole
// rotation's sagitta would add 1.3 % of rho on both sides of every axis
// across the rotation.
WorldBox fillInReach(const Mat4& previous, const Mat4& current, int width, int height,
                         const ReconSettings& recon) {
  const SlicePose a = poseFromMatrix(previous, "the previous frame"), b = poseFromMatrix(current, "the frame");
  const PixelRect r = clipRect(width, height, recon);
  WorldBox box = reachOf(a, r, recon);
  const WorldBox rb = reachOf(b, r, recon);
  box.lo = glm::min(box.lo, rb.lo);
  box.hi = glm::max(box.hi, rb.hi);

  // The rotation between them, as interpolatePose takes it.
  const Quat qa = a.q;
  Quat qb = b.q;
  if (glm::dot(qa, qb) < 0.0) qb = -qb;
  const Quat rel = glm::conjugate(qa) * qb;  // qb = qa * rel
  const double theta = 2.0 * std::acos(std::min(1.0, std::abs(rel.w)));
  // No slice is filled in without fill-in, or across a rotation the
  // reconstructor treats as a jump (the small margin keeps the decision on the
  // safe side of its rounding).
  constexpr double kDegPerRad = 180.0 / 3.14159265358979323846;
  if (!recon.tent.fillIn || theta * kDegPerRad > recon.tent.fillInMaxAngleDeg + 1e-6) return padded(box);

  const int steps = std::clamp(static_cast<int>(std::ceil(theta * kDegPerRad)), 1, 180);
  for (int j = 1; j < steps; ++j) {
    const double t = static_cast<double>(j) / steps;
    const SlicePose p = interpolatePose(a, b, t);
    const WorldBox pb = kernelBox(r, recon, p.u, p.v, p.n, [&](double c, double y) { return p.pixel(c, y); });
    box.lo = glm::min(box.lo, pb.lo);
    box.hi = glm::max(box.hi, pb.hi);
  }

  const Vec3 im(rel.x, rel.y, rel.z);
  const double iml = glm::length(im);
  const bool haveAxis = iml > 1e-12;
  const Vec3 w = haveAxis ? im / iml : Vec3(0.0);  // in a's (u, v, n) axes
  auto distFromAxis = [&](const Vec3& p) { return haveAxis ? glm::length(p - glm::dot(p, w) * w) : glm::length(p); };
  double rho = 0.0, dMax = 0.0;
  const double hl = recon.tent.kernelLateralMm, ha = recon.tent.kernelAxialMm, he = recon.tent.kernelElevationMm;
  for (const auto& [c, y] : corners(r)) {
    const Vec3 pa(c * a.sx + y * a.eyu, y * a.syv, 0.0), pb(c * b.sx + y * b.eyu, y * b.syv, 0.0);
    dMax = std::max(dMax, distFromAxis(pa - pb));
    for (int k = 0; k < 8; ++k) {
      const Vec3 kk((k & 1) ? hl : -hl, (k & 2) ? ha : -ha, (k & 4) ? he : -he);
      rho = std::max({rho, distFromAxis(pa + kk), distFromAxis(pb + kk)});
    }
  }
  const double half = 0.5 * theta / steps;
  const double grow =
      rho * ((1.0 - std::cos(half)) + (half - std::sin(half))) + 0.5 * std::sin(half) * dMax / steps;
  const Vec3 wWorld = haveAxis ? glm::dmat3(a.u, a.v, a.n) * w : Vec3(0.0);
  for (int i = 0; i < 3; ++i) {
    const double g = grow * (haveAxis ? std::sqrt(std::max(0.0, 1.0 - wWorld[i] * wWorld[i])) : 1.0);
    box.lo[i] -= g;
    box.hi[i] += g;
  }
  return padded(box);
}

}  // namespace pp5::gp
