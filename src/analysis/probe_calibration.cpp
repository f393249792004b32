#include "analysis/probe_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <numeric>

#include <Eigen/Dense>
#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::calib {
namespace {

using glm::dvec3;

PatternDots labelled(const PatternDots& leftToRight, bool wire0OnRight) {
  if (!wire0OnRight) return leftToRight;
  return {leftToRight[2], leftToRight[1], leftToRight[0]};
}

// A middle dot's pixel and where the ratio places it in the Probe frame.
struct PointPair {
  Vec2 pixel;
  dvec3 probe;
  std::size_t frame;  // index into the frames vector
  int pattern;
};

std::vector<PointPair> middlePoints(const NWirePhantom& phantom, const std::vector<CalibrationFrame>& frames,
                                    bool wire0OnRight) {
  std::vector<PointPair> out;
  for (std::size_t f = 0; f < frames.size(); ++f) {
    const auto& fr = frames[f];
    PP5_CHECK_EQ(static_cast<int>(fr.dots.size()), phantom.patternCount());
    for (int k = 0; k < phantom.patternCount(); ++k) {
      const PatternDots d = labelled(fr.dots[static_cast<std::size_t>(k)], wire0OnRight);
      const double u = ratioAlong(d[0], d[1], d[2]);
      out.push_back({d[1], transformPoint(fr.phantomToProbe, phantom.middleWirePoint(k, u)), f, k});
    }
  }
  return out;
}

// Image coordinates scaled to about unit size, for well-conditioned fits.
struct Normaliser {
  Vec2 centre{0.0};
  double scale = 1.0;
  Eigen::Vector3d operator()(const Vec2& p) const {
    return {(p.x - centre.x) / scale, (p.y - centre.y) / scale, 1.0};
  }
  // The 3x3 [a b c] acting on normalised (x, y, 1), per output row, as a Mat4
  // on pixels (column 2, the elevation, left zero here).
  Mat4 toPixels(const Eigen::Matrix3d& rows) const {
    Mat4 m(1.0);
    for (int r = 0; r < 3; ++r) {
      const double a = rows(r, 0) / scale, b = rows(r, 1) / scale;
      m[0][r] = a;
      m[1][r] = b;
      m[2][r] = 0.0;
      m[3][r] = rows(r, 2) - a * centre.x - b * centre.y;
    }
    return m;
  }
};

Normaliser normaliserFor(const std::vector<Vec2>& pixels) {
  Normaliser n;
  for (const auto& p : pixels) n.centre += p;
  n.centre /= static_cast<double>(std::max<std::size_t>(pixels.size(), 1));
  double s = 0.0;
  for (const auto& p : pixels) s += glm::length(p - n.centre);
  n.scale = pixels.empty() ? 1.0 : std::max(s / static_cast<double>(pixels.size()), 1e-9);
  return n;
}

// The elevation column: square to the image axes, as long as their mean.
Mat4 withElevationColumn(Mat4 m) {
  const dvec3 c0(m[0]), c1(m[1]);
  const dvec3 n = glm::normalize(glm::cross(c0, c1));
  const double s = 0.5 * (glm::length(c0) + glm::length(c1));
  m[2] = glm::dvec4(n * s, 0.0);
  return m;
}

struct LinearFit {
  Mat4 m{1.0};
  double condition = 0.0;
};

LinearFit fitLinear(const std::vector<PointPair>& pts, const std::vector<char>& use,
                    const std::vector<double>* weights = nullptr) {
  std::vector<Vec2> px;
  for (std::size_t i = 0; i < pts.size(); ++i)
    if (use[i]) px.push_back(pts[i].pixel);
  const Normaliser nz = normaliserFor(px);
  Eigen::MatrixXd A(static_cast<Eigen::Index>(px.size()), 3);
  Eigen::MatrixXd B(static_cast<Eigen::Index>(px.size()), 3);
  Eigen::Index row = 0;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    if (!use[i]) continue;
    const double w = weights ? std::sqrt((*weights)[i]) : 1.0;
    A.row(row) = w * nz(pts[i].pixel).transpose();
    B.row(row) << w * pts[i].probe.x, w * pts[i].probe.y, w * pts[i].probe.z;
    ++row;
  }
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const auto& sv = svd.singularValues();
  LinearFit out;
  out.condition = sv(sv.size() - 1) > 0.0 ? sv(0) / sv(sv.size() - 1) : std::numeric_limits<double>::infinity();
  const Eigen::MatrixXd X = svd.solve(B);  // 3 x 3: column r = output row r
  out.m = nz.toPixels(X.transpose());
  return out;
}

ReprojectionError summarise(const std::vector<double>& d, const std::vector<int>& pattern, int patterns) {
  ReprojectionError e;
  e.points = d.size();
  e.meanPerPattern.assign(static_cast<std::size_t>(patterns), 0.0);
  if (d.empty()) return e;
  std::vector<std::size_t> count(static_cast<std::size_t>(patterns), 0);
  double s = 0.0, s2 = 0.0;
  for (std::size_t i = 0; i < d.size(); ++i) {
    s += d[i];
    s2 += d[i] * d[i];
    e.max = std::max(e.max, d[i]);
    e.meanPerPattern[static_cast<std::size_t>(pattern[i])] += d[i];
    ++count[static_cast<std::size_t>(pattern[i])];
  }
  const double n = static_cast<double>(d.size());
  e.mean = s / n;
  e.rms = std::sqrt(s2 / n);
  e.sd = std::sqrt(std::max(0.0, s2 / n - e.mean * e.mean));
  for (int k = 0; k < patterns; ++k)
    if (count[static_cast<std::size_t>(k)])
      e.meanPerPattern[static_cast<std::size_t>(k)] /= static_cast<double>(count[static_cast<std::size_t>(k)]);
  return e;
}

double distanceOf(const PointPair& p, const Mat4& m) {
  return glm::length(transformPoint(m, dvec3(p.pixel, 0.0)) - p.probe);
}

// Rejects points beyond mean + k sd of `dist` among those in use; true when any
// went. A point within 10 um is never an outlier (exact data would otherwise
// lose points to rounding).
bool rejectOutliers(const std::vector<double>& dist, std::vector<char>& use, double k) {
  double s = 0.0, s2 = 0.0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < dist.size(); ++i)
    if (use[i]) {
      s += dist[i];
      s2 += dist[i] * dist[i];
      ++n;
    }
  if (n < 2) return false;
  const double mean = s / static_cast<double>(n);
  const double sd = std::sqrt(std::max(0.0, s2 / static_cast<double>(n) - mean * mean));
  bool any = false;
  for (std::size_t i = 0; i < dist.size(); ++i)
    if (use[i] && dist[i] > mean + k * sd && dist[i] > 0.01) {
      use[i] = 0;
      any = true;
    }
  return any;
}

// Every dot of every frame with where it belongs in the Probe frame: on the
// line through `point` along `dir` (unit), or at `point` when dir is zero.
struct DotOnWire {
  Vec2 pixel;
  dvec3 point, dir;
};

std::vector<DotOnWire> dotsOnWires(const NWirePhantom& phantom, const std::vector<CalibrationFrame>& frames,
                                   bool wire0OnRight) {
  std::vector<DotOnWire> out;
  for (const auto& fr : frames)
    for (int k = 0; k < phantom.patternCount(); ++k) {
      const PatternDots d = labelled(fr.dots[static_cast<std::size_t>(k)], wire0OnRight);
      // The outer dots lie on their wires' lines; the middle dot at the point
      // the ratio gives (a line with no direction: a point).
      for (int w : {0, 2})
        out.push_back({d[static_cast<std::size_t>(w)], transformPoint(fr.phantomToProbe, phantom.wirePoint(k, w)),
                       glm::normalize(transformVector(fr.phantomToProbe, phantom.wireDirection(k, w)))});
      out.push_back({d[1], transformPoint(fr.phantomToProbe, phantom.middleWirePoint(k, ratioAlong(d[0], d[1], d[2]))),
                     dvec3(0.0)});
    }
  return out;
}

dvec3 offWire(const DotOnWire& d, const Mat4& m) {
  const dvec3 v = transformPoint(m, dvec3(d.pixel, 0.0)) - d.point;
  return v - glm::dot(v, d.dir) * d.dir;
}

// The affine that minimises the summed squared distance of the dots in use
// from their lines or points: linear in the 9 parameters.
Mat4 fitAffineToWires(const std::vector<DotOnWire>& dots, const std::vector<char>& use) {
  std::vector<Vec2> px;
  for (std::size_t i = 0; i < dots.size(); ++i)
    if (use[i]) px.push_back(dots[i].pixel);
  const Normaliser nz = normaliserFor(px);
  const Eigen::Index rows = static_cast<Eigen::Index>(3 * px.size());
  Eigen::MatrixXd J(rows, 9);
  Eigen::VectorXd b(rows);
  Eigen::Index r0 = 0;
  for (std::size_t i = 0; i < dots.size(); ++i) {
    if (!use[i]) continue;
    const auto& d = dots[i];
    const Eigen::Vector3d dir(d.dir.x, d.dir.y, d.dir.z);
    const Eigen::Matrix3d P = Eigen::Matrix3d::Identity() - dir * dir.transpose();
    const Eigen::Vector3d p = nz(d.pixel);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) J.block(r0, 3 * r + c, 3, 1) = P.col(r) * p(c);
    b.segment(r0, 3) = P * Eigen::Vector3d(d.point.x, d.point.y, d.point.z);
    r0 += 3;
  }
  const Eigen::VectorXd x = J.colPivHouseholderQr().solve(b);
  Eigen::Matrix3d X;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) X(r, c) = x(3 * r + c);
  return nz.toPixels(X);
}

// Rotation vector (axis times angle) of a rotation matrix, and back.
Eigen::Vector3d logRotation(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.axis() * aa.angle();
}
Eigen::Matrix3d expRotation(const Eigen::Vector3d& w) {
  const double a = w.norm();
  if (a < 1e-15) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(a, w / a).toRotationMatrix();
}

Mat4 rigidScaleMatrix(const Eigen::Matrix<double, 8, 1>& q) {
  const Eigen::Matrix3d R = expRotation(q.head<3>());
  Mat4 m(1.0);
  for (int r = 0; r < 3; ++r) {
    m[0][r] = R(r, 0) * q(6);
    m[1][r] = R(r, 1) * q(7);
    m[2][r] = 0.0;
    m[3][r] = q(3 + r);
  }
  return m;
}

// The rotation, translation and axis scales nearest an affine's image axes.
Eigen::Matrix<double, 8, 1> rigidScaleFrom(const Mat4& m) {
  const dvec3 c0(m[0]), c1(m[1]);
  const dvec3 x = glm::normalize(c0), yRaw = glm::normalize(c1), z = glm::normalize(glm::cross(x, yRaw));
  Eigen::Matrix3d A;
  A << x.x, yRaw.x, z.x, x.y, yRaw.y, z.y, x.z, yRaw.z, z.z;
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(A, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d R = svd.matrixU() * svd.matrixV().transpose();
  if (R.determinant() < 0) {
    Eigen::Matrix3d U = svd.matrixU();
    U.col(2) *= -1.0;
    R = U * svd.matrixV().transpose();
  }
  Eigen::Matrix<double, 8, 1> q;
  q.head<3>() = logRotation(R);
  q(3) = m[3][0], q(4) = m[3][1], q(5) = m[3][2];
  q(6) = glm::length(c0), q(7) = glm::length(c1);
  return q;
}

// Levenberg-Marquardt over a rotation, a translation and two axis scales,
// starting from the rigid-plus-scale nearest `start`. `residuals(m)` gives the
// stacked residual vector for an ImageToProbe.
template <class Residuals>
Mat4 fitRigidScale(const Mat4& start, Residuals&& residualsOf) {
  Eigen::Matrix<double, 8, 1> q = rigidScaleFrom(start);
  auto residuals = [&](const Eigen::Matrix<double, 8, 1>& p) {
    std::vector<double> r = residualsOf(rigidScaleMatrix(p));
    return Eigen::Map<Eigen::VectorXd>(r.data(), static_cast<Eigen::Index>(r.size())).eval();
  };
  double lambda = 1e-3;
  Eigen::VectorXd r = residuals(q);
  double cost = r.squaredNorm();
  for (int it = 0; it < 100; ++it) {
    Eigen::MatrixXd J(r.size(), 8);
    for (int j = 0; j < 8; ++j) {
      const double h = j < 3 ? 1e-6 : (j < 6 ? 1e-4 : 1e-7);
      Eigen::Matrix<double, 8, 1> a = q, b = q;
      a(j) += h;
      b(j) -= h;
      J.col(j) = (residuals(a) - residuals(b)) / (2.0 * h);
    }
    const Eigen::MatrixXd H = J.transpose() * J;
    const Eigen::VectorXd g = J.transpose() * r;
    bool improved = false;
    double gain = 0.0;
    for (int tries = 0; tries < 10 && !improved; ++tries) {
      Eigen::MatrixXd Hd = H;
      Hd.diagonal() *= 1.0 + lambda;
      const Eigen::Matrix<double, 8, 1> qn = q + Hd.ldlt().solve(-g);
      const Eigen::VectorXd rn = residuals(qn);
      const double cn = rn.squaredNorm();
      if (cn < cost) {
        gain = (cost - cn) / std::max(cost, 1e-300);
        q = qn, r = rn, cost = cn;
        lambda = std::max(lambda / 10.0, 1e-12);
        improved = true;
      } else {
        lambda *= 10.0;
      }
    }
    if (!improved || gain < 1e-12) break;
  }
  return rigidScaleMatrix(q);
}

double rotationAngleDeg(const Mat4& a, const Mat4& b) {
  const glm::dmat3 ra(a), rb(b);
  const glm::dmat3 rel = glm::transpose(ra) * rb;
  // Remove any scale (PhantomToProbe is rigid, but be safe).
  const double tr = rel[0][0] + rel[1][1] + rel[2][2];
  return std::acos(std::clamp((tr - 1.0) / 2.0, -1.0, 1.0)) * 180.0 / std::numbers::pi;
}

}  // namespace

ReprojectionError middleWireError(const NWirePhantom& phantom, const std::vector<CalibrationFrame>& frames,
                                  const Mat4& imageToProbe, bool wire0OnRight) {
  const auto pts = middlePoints(phantom, frames, wire0OnRight);
  std::vector<double> d;
  std::vector<int> pat;
  for (const auto& p : pts) {
    d.push_back(distanceOf(p, imageToProbe));
    pat.push_back(p.pattern);
  }
  return summarise(d, pat, phantom.patternCount());
}

std::vector<double> wireErrors(const NWirePhantom& phantom, const std::vector<CalibrationFrame>& frames,
                               const Mat4& imageToProbe, bool wire0OnRight) {
  // dotsOnWires lists each pattern's dots as wire 0, wire 2, then the middle one.
  const auto dots = dotsOnWires(phantom, frames, wire0OnRight);
  const std::size_t patterns = static_cast<std::size_t>(phantom.patternCount());
  std::vector<double> sum(3 * patterns, 0.0);
  std::vector<std::size_t> count(3 * patterns, 0);
  constexpr int kWireOf[3] = {0, 2, 1};
  for (std::size_t i = 0; i < dots.size(); ++i) {
    const std::size_t k = (i / 3) % patterns;
    const std::size_t slot = 3 * k + static_cast<std::size_t>(kWireOf[i % 3]);
    sum[slot] += glm::length(offWire(dots[i], imageToProbe));
    ++count[slot];
  }
  for (std::size_t j = 0; j < sum.size(); ++j)
    if (count[j]) sum[j] /= static_cast<double>(count[j]);
  return sum;
}

double cornerDistanceMm(const Mat4& a, const Mat4& b, int width, int height) {
  const double w = width - 1.0, h = height - 1.0;
  double worst = 0.0;
  for (const Vec2 p : {Vec2(0, 0), Vec2(w, 0), Vec2(0, h), Vec2(w, h), Vec2(w / 2, h / 2)})
    worst = std::max(worst, glm::length(transformPoint(a, dvec3(p, 0.0)) - transformPoint(b, dvec3(p, 0.0))));
  return worst;
}

CalibrationResult calibrateProbe(const NWirePhantom& phantom, const std::vector<CalibrationFrame>& frames,
                                 const CalibrationOptions& o) {
  if (static_cast<int>(frames.size()) < o.minFrames)
    throw InputError(fmt::format(
        "the N-wire pattern was found in {} frames; a calibration needs at least {}: record the phantom longer, "
        "with all of its wires in view",
        frames.size(), o.minFrames));
  CalibrationResult res;
  res.frames = frames.size();
  for (std::size_t i = 0; i < frames.size(); ++i) {
    res.rotationSpreadDeg = std::max(res.rotationSpreadDeg, rotationAngleDeg(frames[0].phantomToProbe, frames[i].phantomToProbe));
    for (std::size_t j = i + 1; j < frames.size(); ++j)
      res.translationSpreadMm = std::max(res.translationSpreadMm,
                                         glm::length(dvec3(frames[i].phantomToProbe[3]) - dvec3(frames[j].phantomToProbe[3])));
  }
  // A pose repeated in every frame leaves the tracker's and the phantom
  // registration's errors unaveraged, and the wires' direction unsampled.
  if (res.rotationSpreadDeg < 2.0 && res.translationSpreadMm < 2.0)
    throw InputError(fmt::format(
        "too little probe motion: the probe turned at most {:.2f} degrees and moved at most {:.2f} mm over the phantom; "
        "record it again while sliding the probe along the wires and tilting it a few degrees each way",
        res.rotationSpreadDeg, res.translationSpreadMm));

  // Which end of the lines is wire 0: the labelling whose linear fit fits best.
  LinearFit best;
  std::vector<PointPair> bestPts;
  std::vector<char> bestUse;
  double bestRms = std::numeric_limits<double>::infinity();
  for (bool right : {false, true}) {
    auto pts = middlePoints(phantom, frames, right);
    std::vector<char> use(pts.size(), 1);
    LinearFit fit = fitLinear(pts, use);
    for (int round = 0; round < o.outlierRounds; ++round) {
      std::vector<double> d(pts.size());
      for (std::size_t i = 0; i < pts.size(); ++i) d[i] = distanceOf(pts[i], fit.m);
      if (!rejectOutliers(d, use, o.outlierSd)) break;
      fit = fitLinear(pts, use);
    }
    double s2 = 0.0;
    std::size_t n = 0;
    for (std::size_t i = 0; i < pts.size(); ++i)
      if (use[i]) {
        const double d = distanceOf(pts[i], fit.m);
        s2 += d * d;
        ++n;
      }
    const double rms = std::sqrt(s2 / static_cast<double>(std::max<std::size_t>(n, 1)));
    if (rms < bestRms) {
      bestRms = rms;
      best = fit;
      bestPts = std::move(pts);
      bestUse = std::move(use);
      res.wire0OnRight = right;
    }
  }
  res.conditionNumber = best.condition;
  if (!(best.condition < 1e6))
    throw InputError(fmt::format("the calibration is singular (condition number {:.3g}): the middle wires' dots do not "
                                 "span the image; record frames with the whole phantom in view",
                                 best.condition));
  res.pointsRejected = static_cast<std::size_t>(std::count(bestUse.begin(), bestUse.end(), 0));
  Mat4 m = withElevationColumn(best.m);
  res.linearImageToProbe = m;
  res.linearError = middleWireError(phantom, frames, m, res.wire0OnRight);

  const auto dots = dotsOnWires(phantom, frames, res.wire0OnRight);
  std::vector<char> dotUse(dots.size(), 1);
  const bool rigid = o.model == CalibrationModel::RigidScale;
  if (o.refinement == CalibrationRefinement::AllWires) {
    auto fitDots = [&](const Mat4& start) {
      if (!rigid) return fitAffineToWires(dots, dotUse);
      return fitRigidScale(start, [&](const Mat4& mm) {
        std::vector<double> r;
        for (std::size_t i = 0; i < dots.size(); ++i)
          if (dotUse[i]) {
            const dvec3 v = offWire(dots[i], mm);
            r.insert(r.end(), {v.x, v.y, v.z});
          }
        return r;
      });
    };
    Mat4 fit = fitDots(m);
    for (int round = 0; round < o.outlierRounds; ++round) {
      std::vector<double> d(dots.size());
      for (std::size_t i = 0; i < dots.size(); ++i) d[i] = glm::length(offWire(dots[i], fit));
      if (!rejectOutliers(d, dotUse, o.outlierSd)) break;
      fit = fitDots(fit);
    }
    m = withElevationColumn(fit);
    res.dotsRejected = static_cast<std::size_t>(std::count(dotUse.begin(), dotUse.end(), 0));
  } else if (o.refinement == CalibrationRefinement::MeanDistance || rigid) {
    // Iteratively reweighted least squares: weights 1 / distance turn the sum
    // of squares into the sum of distances (floored at 10 um, so a point that
    // fits exactly does not take over). Without MeanDistance, a rigid model
    // keeps unit weights: its least squares on the middle wires.
    const bool mean = o.refinement == CalibrationRefinement::MeanDistance;
    std::vector<double> w(bestPts.size(), 1.0);
    Mat4 fit = m;
    for (int it = 0; it < (mean ? 30 : 1); ++it) {
      if (mean)
        for (std::size_t i = 0; i < bestPts.size(); ++i) w[i] = 1.0 / std::max(distanceOf(bestPts[i], fit), 0.01);
      Mat4 next;
      if (!rigid) {
        next = fitLinear(bestPts, bestUse, &w).m;
      } else {
        next = fitRigidScale(fit, [&](const Mat4& mm) {
          std::vector<double> r;
          for (std::size_t i = 0; i < bestPts.size(); ++i)
            if (bestUse[i]) {
              const dvec3 v = (transformPoint(mm, dvec3(bestPts[i].pixel, 0.0)) - bestPts[i].probe) * std::sqrt(w[i]);
              r.insert(r.end(), {v.x, v.y, v.z});
            }
          return r;
        });
      }
      const double change = cornerDistanceMm(fit, next, 1000, 1000);
      fit = next;
      if (change < 1e-5) break;
    }
    m = withElevationColumn(fit);
  }
  double s2 = 0.0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < dots.size(); ++i)
    if (dotUse[i]) {
      const double d = glm::length(offWire(dots[i], m));
      s2 += d * d;
      ++n;
    }
  res.wireDistanceRms = std::sqrt(s2 / static_cast<double>(std::max<std::size_t>(n, 1)));
  res.imageToProbe = m;
  res.error = middleWireError(phantom, frames, m, res.wire0OnRight);
  return res;
}

}  // namespace pp5::calib
