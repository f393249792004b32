#pragma once
// Rigid and affine transforms on GLM (double precision), and PLUS's named
// calibration chain. Names follow PLUS: "ImageToProbe" maps Image coordinates
// into Probe coordinates, so ImageToReference = inv(ReferenceToTracker) *
// ProbeToTracker * ImageToProbe.
//
// GLM stores matrices column-major (m[col][row]); PLUS writes them row-major.
// Always go through fromRowMajor/toRowMajor at the file boundary.
#include <array>
#include <numbers>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <glm/glm.hpp>

namespace pp5 {

using Mat4 = glm::dmat4;
using Vec3 = glm::dvec3;
using Vec4 = glm::dvec4;

Mat4 fromRowMajor(const std::array<double, 16>& v);
std::array<double, 16> toRowMajor(const Mat4& m);
// "a b c ... p" with 16 row-major numbers. Returns nullopt (and fills *why) on
// a wrong count or a token that is not a finite number.
std::optional<Mat4> parseRowMajor(const std::string& text, std::string* why = nullptr);
// Row-major text, enough digits to round-trip doubles exactly.
std::string formatRowMajor(const Mat4& m);

// Degrees to radians.
inline constexpr double kDegToRad = std::numbers::pi / 180.0;

// Transforms a point (w = 1).
inline Vec3 transformPoint(const Mat4& m, const Vec3& p) { return Vec3(m * Vec4(p, 1.0)); }
inline Vec3 transformVector(const Mat4& m, const Vec3& v) { return Vec3(m * Vec4(v, 0.0)); }
// The largest distance any of `points` moves between poses a and b (the
// points in the frame both map from): how far a frame moved, as the 1990
// system's constant-interval capture measures it.
double largestDisplacement(const Mat4& a, const Mat4& b, std::span<const Vec3> points);

bool isFinite(const Mat4& m);
// Rotation part orthonormal (within tol) and proper (no reflection), last row (0 0 0 1).
bool isRigid(const Mat4& m, double tol = 1e-6);
// Inverse of an affine matrix (last row 0 0 0 1); exact for rigid ones. A
// singular matrix gives non-finite entries (check with isFinite); a non-affine
// one falls back to the general inverse.
Mat4 affineInverse(const Mat4& m);

// Rigid helpers.
Mat4 translation(const Vec3& t);
Mat4 rotationAxisAngle(const Vec3& axis, double radians);
Mat4 scaling(const Vec3& s);

// PLUS's calibration chain for one frame.
struct CalibrationChain {
  Mat4 imageToProbe{1.0};        // calibration, includes mm per pixel
  Mat4 probeToTracker{1.0};      // per frame, from the tracker
  Mat4 referenceToTracker{1.0};  // per frame, from the tracker
  Mat4 imageToReference() const { return affineInverse(referenceToTracker) * probeToTracker * imageToProbe; }
};

// A set of named coordinate-frame transforms ("AToB"), as PLUS's
// vtkPlusTransformRepository keeps them. Any chain through known transforms and
// their inverses can be asked for.
class TransformRepository {
public:
  // Adds or replaces From->To. Replacing keeps the inverse consistent: one edge
  // is kept per pair of frames, so setting BToA replaces an earlier AToB.
  // From and To must be non-empty and differ (InvariantError otherwise).
  void set(const std::string& from, const std::string& to, const Mat4& m, bool valid = true);
  // From->To through any chain of known transforms (breadth-first over frames,
  // so the chain with the fewest links). Identity when From == To. nullopt when
  // no chain exists or a link on the chain is invalid.
  std::optional<Mat4> get(const std::string& from, const std::string& to) const;
  // The frames on the chain From..To (inclusive), empty when none.
  std::vector<std::string> path(const std::string& from, const std::string& to) const;
  std::vector<std::string> frames() const;

private:
  struct Edge {
    std::string from, to;
    Mat4 m;
    bool valid;
  };
  std::vector<Edge> edges_;
};

// Splits "ProbeToTracker" into {"Probe", "Tracker"}; nullopt when there is no "To".
// Only a "To" followed by an uppercase letter separates the frames, so
// "StylusTipToReference" and "ToolToReference" split as expected. When several
// such "To"s give a non-empty From that starts with an uppercase letter
// ("ImageToTorsoToReference"), the name is ambiguous and, as in PLUS, nullopt.
std::optional<std::pair<std::string, std::string>> splitTransformName(const std::string& name);

}  // namespace pp5
