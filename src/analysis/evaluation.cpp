#include "analysis/evaluation.hpp"

#include <cmath>

#include "core/error.hpp"

namespace pp5::gp {

std::vector<std::uint8_t> sweptRegion(const Grid& g, const std::vector<Mat4>& poses, int width, int height) {
  std::vector<std::uint8_t> mask(g.voxelCount(), 0);
  struct Plane {
    Vec3 origin, u, v, n;  // u, v: pixel step vectors; n: unit normal
    double uu, vv;
  };
  auto plane = [](const Mat4& m) {
    Plane p;
    p.origin = transformPoint(m, Vec3(0.0));
    p.u = transformVector(m, Vec3(1, 0, 0));
    p.v = transformVector(m, Vec3(0, 1, 0));
    p.n = glm::normalize(glm::cross(p.u, p.v));
    p.uu = glm::dot(p.u, p.u);
    p.vv = glm::dot(p.v, p.v);
    return p;
  };
  // Inside the image rectangle when projected along the normal.
  auto inside = [&](const Plane& p, const Vec3& x) {
    const Vec3 d = x - p.origin;
    const double i = glm::dot(d, p.u) / p.uu, j = glm::dot(d, p.v) / p.vv;
    return i >= 0.0 && j >= 0.0 && i <= width - 1 && j <= height - 1;
  };
  for (std::size_t f = 0; f + 1 < poses.size(); ++f) {
    const Plane a = plane(poses[f]), b = plane(poses[f + 1]);
    // Only voxels inside the pair's bounding box can be between them.
    Vec3 lo(1e300), hi(-1e300);
    for (const Mat4* m : {&poses[f], &poses[f + 1]})
      for (const Vec3 c : {Vec3(0, 0, 0), Vec3(width - 1, 0, 0), Vec3(0, height - 1, 0), Vec3(width - 1, height - 1, 0)}) {
        lo = glm::min(lo, transformPoint(*m, c));
        hi = glm::max(hi, transformPoint(*m, c));
      }
    const Index3 vlo = glm::max(Index3(glm::floor(g.worldToVoxel(lo))), Index3(0));
    const Index3 vhi = glm::min(Index3(glm::ceil(g.worldToVoxel(hi))), g.dims - Index3(1));
    for (std::int64_t k = vlo.z; k <= vhi.z; ++k)
      for (std::int64_t j = vlo.y; j <= vhi.y; ++j)
        for (std::int64_t i = vlo.x; i <= vhi.x; ++i) {
          const Vec3 x = g.voxelToWorld(Vec3(i, j, k));
          const double sa = glm::dot(x - a.origin, a.n), sb = glm::dot(x - b.origin, b.n);
          // Between the planes: the signed distances differ in sign (normals of
          // consecutive frames point the same way for any sensible sweep).
          if (sa * sb > 0.0) continue;
          if (inside(a, x) && inside(b, x)) mask[g.linear(i, j, k)] = 1;
        }
  }
  return mask;
}

namespace {

// Sets every voxel within `radius` voxels of a set one along `axis` (a max
// filter of width 2 radius + 1, in place): two passes per line that carry the
// distance to the last set voxel.
void dilateAlong(std::vector<std::uint8_t>& m, const Index3& dims, int axis, std::int64_t radius) {
  if (radius <= 0) return;
  const std::int64_t stride[3] = {1, dims.x, dims.x * dims.y};
  const std::int64_t n = dims[axis];
  const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
  std::vector<std::uint8_t> out(static_cast<std::size_t>(n));
  for (std::int64_t v = 0; v < dims[a2]; ++v)
    for (std::int64_t u = 0; u < dims[a1]; ++u) {
      std::uint8_t* line = m.data() + u * stride[a1] + v * stride[a2];
      const std::int64_t st = stride[axis];
      std::int64_t last = -(radius + 1);
      for (std::int64_t i = 0; i < n; ++i) {
        if (line[i * st]) last = i;
        out[static_cast<std::size_t>(i)] = i - last <= radius;
      }
      last = n + radius + 1;
      for (std::int64_t i = n - 1; i >= 0; --i) {
        if (line[i * st]) last = i;
        if (last - i <= radius) out[static_cast<std::size_t>(i)] = 1;
      }
      for (std::int64_t i = 0; i < n; ++i) line[i * st] = out[static_cast<std::size_t>(i)];
    }
}

}  // namespace

TruthMetrics compareWithTruth(const Volume& recon, const CoveredFn& covered, const Volume& truth,
                              const std::vector<std::uint8_t>& swept, double edgeMm) {
  const Grid& g = recon.grid;
  const Grid& t = truth.grid;
  const bool same = g.dims == t.dims && glm::all(glm::lessThan(glm::abs(g.origin - t.origin), Vec3(1e-6))) &&
                    glm::all(glm::lessThan(glm::abs(g.spacing - t.spacing), Vec3(1e-9)));
  if (!same)
    throw InputError(fmt::format(
        "the reconstruction grid ({}x{}x{} at {} {} {} mm) differs from the truth volume's ({}x{}x{} at {} {} {} mm)",
        g.dims.x, g.dims.y, g.dims.z, g.origin.x, g.origin.y, g.origin.z, t.dims.x, t.dims.y, t.dims.z, t.origin.x,
        t.origin.y, t.origin.z));
  PP5_CHECK(swept.empty() || swept.size() == g.voxelCount());
  TruthMetrics m;
  m.voxels = g.voxelCount();
  PP5_CHECK(edgeMm >= 0.0);
  m.edgeMm = edgeMm;
  double background = INFINITY;
  for (std::size_t i = 0; i < m.voxels; ++i) background = std::min(background, truth.value(i));
  auto isTissue = [&](double t) { return t > background + 1.0; };
  std::vector<std::uint8_t> nearTissue(m.voxels, 0);
  for (std::size_t i = 0; i < m.voxels; ++i) nearTissue[i] = isTissue(truth.value(i)) ? 1 : 0;
  for (int a = 0; a < 3; ++a)
    dilateAlong(nearTissue, g.dims, a, static_cast<std::int64_t>(std::floor(edgeMm / g.spacing[a] + 1e-9)));
  double sumSq = 0.0, sumAbs = 0.0, sum = 0.0, tSq = 0.0, tAbs = 0.0, tSum = 0.0;
  double eSq = 0.0, eSum = 0.0, fSq = 0.0;
  for (std::size_t i = 0; i < m.voxels; ++i) {
    const bool c = covered(i);
    const bool s = swept.empty() || swept[i];
    if (c) ++m.covered;
    if (!swept.empty() && swept[i]) {
      ++m.swept;
      if (!c) ++m.sweptHoles;
    }
    if (c && s) {
      const double t = truth.value(i);
      const double d = recon.value(i) - t;
      sumSq += d * d;
      sumAbs += std::abs(d);
      sum += d;
      ++m.compared;
      if (isTissue(t)) {
        tSq += d * d;
        tAbs += std::abs(d);
        tSum += d;
        ++m.tissueCompared;
      } else if (nearTissue[i]) {
        eSq += d * d;
        eSum += d;
        ++m.edgeCompared;
      } else {
        fSq += d * d;
        ++m.farCompared;
      }
    }
  }
  if (m.compared > 0) {
    m.rmse = std::sqrt(sumSq / static_cast<double>(m.compared));
    m.mae = sumAbs / static_cast<double>(m.compared);
    m.bias = sum / static_cast<double>(m.compared);
  }
  if (m.tissueCompared > 0) {
    m.rmseTissue = std::sqrt(tSq / static_cast<double>(m.tissueCompared));
    m.maeTissue = tAbs / static_cast<double>(m.tissueCompared);
    m.biasTissue = tSum / static_cast<double>(m.tissueCompared);
  }
  if (m.edgeCompared > 0) {
    m.rmseEdge = std::sqrt(eSq / static_cast<double>(m.edgeCompared));
    m.biasEdge = eSum / static_cast<double>(m.edgeCompared);
  }
  if (m.farCompared > 0) m.rmseFar = std::sqrt(fSq / static_cast<double>(m.farCompared));
  // No comparison or a non-finite error has no PSNR (never a perfect one).
  m.psnrDb = m.compared == 0 || !std::isfinite(m.rmse) ? NAN
             : m.rmse > 0.0                            ? 20.0 * std::log10(255.0 / m.rmse)
                                                       : INFINITY;
  return m;
}

std::optional<double> sampleCovered(const Volume& v, const CoveredFn& covered, const Vec3& world) {
  const Grid& g = v.grid;
  const Vec3 p = g.worldToVoxel(world);
  const Vec3 f0 = glm::floor(p);
  const Index3 i0(f0);
  if (i0.x < 0 || i0.y < 0 || i0.z < 0 || i0.x + 1 >= g.dims.x || i0.y + 1 >= g.dims.y || i0.z + 1 >= g.dims.z)
    return std::nullopt;
  const Vec3 t = p - f0;
  double sum = 0.0;
  for (int c = 0; c < 8; ++c) {
    const Index3 d(c & 1, (c >> 1) & 1, (c >> 2) & 1);
    const std::size_t idx = g.linear(i0.x + d.x, i0.y + d.y, i0.z + d.z);
    if (!covered(idx)) return std::nullopt;
    const double w = (d.x ? t.x : 1 - t.x) * (d.y ? t.y : 1 - t.y) * (d.z ? t.z : 1 - t.z);
    sum += w * v.value(idx);
  }
  return sum;
}

void LeaveOutMetrics::finish() {
  if (pixelsCompared == 0) return;
  mae = sumAbs_ / static_cast<double>(pixelsCompared);
  bias = sum_ / static_cast<double>(pixelsCompared);
  rmse = std::sqrt(sumSq_ / static_cast<double>(pixelsCompared));
}

void compareHeldOutFrame(const Volume& v, const CoveredFn& covered, const Frame& f, const Mat4& m,
                         const std::vector<PixelRun>& runs, LeaveOutMetrics& out, LeaveOutReading reading) {
  ++out.framesHeldOut;
  const Vec3 o = transformPoint(m, Vec3(0.0));
  const Vec3 du = transformVector(m, Vec3(1, 0, 0)), dv = transformVector(m, Vec3(0, 1, 0));
  for (const PixelRun& r : runs)
    for (int x = r.x0; x <= r.x1; ++x) {
      const int y = r.y;
      const auto s = sampleCovered(v, covered, o + du * static_cast<double>(x) + dv * static_cast<double>(y));
      if (!s) {
        ++out.pixelsSkipped;
        continue;
      }
      double value = *s;
      if (reading == LeaveOutReading::PlusGreyLevels) {
        value = std::floor(value + 0.5);  // the grey level PLUS's volume holds
        if (value == 0.0) {               // "value != 0 as coverage"
          ++out.pixelsSkipped;
          continue;
        }
      }
      out.add(value - f.value(x, y));
    }
}

}  // namespace pp5::gp
