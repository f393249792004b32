#pragma once
// Where a frame's slice lies and what it can reach: the one place that turns
// an image-to-reference matrix into a slice's axes, interpolates the fill-in
// slices between two frames, and bounds the voxels the tent kernel can write
// from them. The tent reconstructor (reconstruction/splat_tent.cpp) splats with it, and
// the host's schedule (pipeline/schedule.hpp) decides with it which GPs a
// frame reaches, so the two cannot disagree.
#include <string>

#include <glm/gtc/quaternion.hpp>

#include "core/transform.hpp"
#include "reconstruction/reconstruction.hpp"
#include "reconstruction/world_box.hpp"

namespace pp5::gp {

using Quat = glm::dquat;

// A slice's placement: pixel (c, r) lies at origin + (c*sx + r*eyu)*u + r*syv*v.
// u is the image x axis, n = normalize(x cross y), v = n cross u; the upper
// triangular (sx, eyu, syv) keeps any pixel scale and shear of the matrix.
struct SlicePose {
  Vec3 origin{0.0};
  Vec3 ex{1, 0, 0}, ey{0, 1, 0};  // the matrix's image x and y axes (pixel (c, r) at origin + c ex + r ey)
  Vec3 u{1, 0, 0}, v{0, 1, 0}, n{0, 0, 1};
  double sx = 1, eyu = 0, syv = 1;
  Quat q{1, 0, 0, 0};  // rotation with columns u, v, n
  Vec3 pixel(double c, double r) const { return origin + (c * sx + r * eyu) * u + (r * syv) * v; }
};


// The slice of an image-to-reference matrix. InputError naming `what` when it
// is not finite, not affine, or maps the image onto a line or a point.
SlicePose poseFromMatrix(const Mat4& m, const std::string& what);
// Rotation angle between two slices' orientations, radians.
double rotationAngle(const SlicePose& a, const SlicePose& b);
// The slice at t in [0, 1] between a and b: the image origin linear, the
// rotation by slerp (the short way), the pixel steps linear.
SlicePose interpolatePose(const SlicePose& a, const SlicePose& b, double t);
// The fill-in slices between two frames whose pixel rectangles' corners moved
// by up to maxCornerDisplacementMm (the rule and its reason: slice_geometry.cpp).
int fillInCount(double maxCornerDisplacementMm, double elevationHalfWidthMm);

// The world box around every voxel that inserting a frame of width x height
// pixels at `imageToReference` can change with the tent kernel of `recon`:
// the clip rectangle's pixel centres (the whole frame when none is set)
// grown by the kernel's half-widths along the slice's own axes, then boxed in
// world axes.
WorldBox frameReach(const Mat4& imageToReference, int width, int height, const ReconSettings& recon);
// The same for the fill-in slices between two consecutive frames (poses
// interpolated by interpolatePose), whatever their number, with both frames'
// reaches: the union of the reaches of both frames and of interpolated slices
// at most 1 degree of rotation apart, grown by the sagitta of the rotation
// between neighbours over the frame's largest radius. Just the two frames'
// union when recon.tent.fillIn is off or the rotation exceeds
// recon.tent.fillInMaxAngleDeg (a jump: nothing is filled in).
WorldBox fillInReach(const Mat4& previous, const Mat4& current, int width, int height, const ReconSettings& recon);

}  // namespace pp5::gp
