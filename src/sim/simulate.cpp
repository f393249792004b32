#include "sim/simulate.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <map>
#include <mutex>
#include <string>
#include <thread>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::sim {

namespace {

int resolveThreads(int threads) {
  if (threads > 0) return threads;
  return std::max(1u, std::thread::hardware_concurrency());
}

std::string tripleText(double a, double b, double c) { return fmt::format("{} {} {}", a, b, c); }

}  // namespace

SweepSimulator::SweepSimulator(const SimSettings& s)
    : settings_(s), phantom_(makePhantom(s.phantom)), probe_(makeProbe(s.probe)) {
  bmode_ = std::make_unique<BModeSimulator>(phantom_, probe_, settings_.bmode, settings_.seed);
  sweep_ = planSweep(settings_, phantom_.scan, imageCornersInProbe(probe_));
}

Mat4 SweepSimulator::imageToReference(std::size_t i) const {
  return affineInverse(sweep_.referenceToTracker) * sweep_.frames.at(i).probeToTracker * probe_.imageToProbe();
}

Mat4 SweepSimulator::trueImageToReference(std::size_t i) const {
  return affineInverse(sweep_.referenceToTracker) * sweep_.frames.at(i).trueProbeToTracker * probe_.imageToProbe();
}

Frame SweepSimulator::frame(std::size_t i, BModeDebug* debug) const {
  const CapturedFrame& c = sweep_.frames.at(i);
  Frame f;
  const Mat4 trueProbeToReference = affineInverse(sweep_.referenceToTracker) * c.trueProbeToTracker;
  bmode_->render(trueProbeToReference, c.videoFrame, f, debug);
  f.index = i;
  f.timestamp = c.timestamp;
  f.imageValid = true;
  f.setTransform("ProbeToTracker", c.probeToTracker);
  f.setTransform("ReferenceToTracker", sweep_.referenceToTracker);
  f.setTransform("TrueProbeToTracker", c.trueProbeToTracker);
  if (c.hasArm) {
    f.customFields.emplace_back("ArmCounts", fmt::format("{} {} {}", c.armCounts[0], c.armCounts[1], c.armCounts[2]));
    f.customFields.emplace_back("ArmPosition",
                                tripleText(c.armReported.xMm, c.armReported.yMm, c.armReported.thetaDeg));
  }
  return f;
}

void SweepSimulator::run(int threads, const std::function<void(Frame&&)>& sink,
                         const std::function<void(std::size_t, std::size_t)>& progress) const {
  const std::size_t n = frameCount();
  const auto workers = static_cast<std::size_t>(resolveThreads(threads));
  // Workers render frames a bounded distance ahead; this thread hands them
  // to `sink` strictly in order, so the output never depends on which worker
  // finished first, and writing overlaps with rendering.
  const std::size_t window = 2 * workers;
  std::mutex mutex;
  std::condition_variable cv;
  std::map<std::size_t, Frame> ready;
  std::size_t nextToRender = 0, nextToEmit = 0;
  std::exception_ptr error;

  auto worker = [&] {
    for (;;) {
      std::size_t i = 0;
      {
        std::unique_lock lock(mutex);
        cv.wait(lock, [&] { return error || nextToRender >= n || nextToRender < nextToEmit + window; });
        if (error || nextToRender >= n) return;
        i = nextToRender++;
      }
      try {
        Frame f = frame(i);
        std::lock_guard lock(mutex);
        ready.emplace(i, std::move(f));
      } catch (...) {
        std::lock_guard lock(mutex);
        if (!error) error = std::current_exception();
      }
      cv.notify_all();
    }
  };
  std::vector<std::thread> pool;
  for (std::size_t k = 0; k < std::min(workers, n); ++k) pool.emplace_back(worker);

  while (nextToEmit < n) {
    Frame f;
    {
      std::unique_lock lock(mutex);
      cv.wait(lock, [&] { return error || ready.count(nextToEmit) > 0; });
      if (error) break;
      f = std::move(ready.at(nextToEmit));
      ready.erase(nextToEmit);
    }
    try {
      sink(std::move(f));
      if (progress) progress(nextToEmit + 1, n);
    } catch (...) {
      std::lock_guard lock(mutex);
      error = std::current_exception();
    }
    {
      std::lock_guard lock(mutex);
      ++nextToEmit;
    }
    cv.notify_all();
  }
  cv.notify_all();
  for (auto& t : pool) t.join();
  if (error) std::rethrow_exception(error);
}

std::vector<Vec3> imageCornersInProbe(const ProbeModel& probe) {
  const Mat4 m = probe.imageToProbe();
  const double w = probe.width - 1, h = probe.height - 1;
  return {transformPoint(m, {0, 0, 0}), transformPoint(m, {w, 0, 0}), transformPoint(m, {0, h, 0}),
          transformPoint(m, {w, h, 0})};
}

Grid fitGrid(const std::vector<Mat4>& imageToReference, int width, int height, const Vec3& spacing, double marginMm) {
  PP5_CHECK(!imageToReference.empty());
  Vec3 lo(std::numeric_limits<double>::max()), hi(std::numeric_limits<double>::lowest());
  const double w = width - 1, h = height - 1;
  for (const Mat4& m : imageToReference)
    for (const Vec3& px : {Vec3(0, 0, 0), Vec3(w, 0, 0), Vec3(0, h, 0), Vec3(w, h, 0)}) {
      const Vec3 p = transformPoint(m, px);
      lo = glm::min(lo, p);
      hi = glm::max(hi, p);
    }
  lo -= Vec3(marginMm);
  hi += Vec3(marginMm);
  Grid g;
  g.origin = lo;
  g.spacing = spacing;
  for (int i = 0; i < 3; ++i) g.dims[i] = static_cast<std::int64_t>(std::ceil((hi[i] - lo[i]) / spacing[i])) + 1;
  return g;
}

Volume truthVolume(const Phantom& phantom, const BModeSimulator& bmode, const Grid& grid, ScalarType type,
                   int threads, std::uint64_t memoryLimitBytes) {
  checkGridFits(grid, static_cast<std::uint64_t>(scalarBytes(type)), "truth volume", memoryLimitBytes);
  Volume vol;
  vol.allocate(grid, type);
  std::array<double, kTissueCount> level{};
  for (int t = 0; t < kTissueCount; ++t) level[static_cast<std::size_t>(t)] = bmode.displayLevel(static_cast<Tissue>(t));
  auto levelOf = [&](Tissue t) { return level[static_cast<std::size_t>(t)]; };
  const double halfDiagonal = 0.5 * glm::length(grid.spacing);

  auto slices = [&](std::int64_t k0, std::int64_t step) {
    for (std::int64_t k = k0; k < grid.dims.z; k += step)
      for (std::int64_t j = 0; j < grid.dims.y; ++j)
        for (std::int64_t i = 0; i < grid.dims.x; ++i) {
          const Vec3 p = grid.voxelToWorld(Vec3(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)));
          const Phantom::Sample s = phantom.sample(p);
          double value = levelOf(s.tissue);
          if (s.clearance < halfDiagonal) {
            // A boundary may cross the voxel: average 2 x 2 x 2 sub-samples.
            value = 0.0;
            for (int c = 0; c < 8; ++c) {
              const Vec3 o((c & 1) ? 0.25 : -0.25, (c & 2) ? 0.25 : -0.25, (c & 4) ? 0.25 : -0.25);
              value += levelOf(phantom.tissueAt(p + o * grid.spacing));
            }
            value /= 8.0;
          }
          vol.setValue(grid.linear(i, j, k), value);
        }
  };
  const int n = std::max(1, std::min<int>(resolveThreads(threads), static_cast<int>(grid.dims.z)));
  if (n == 1) {
    slices(0, 1);
  } else {
    std::vector<std::thread> pool;
    for (int t = 0; t < n; ++t) pool.emplace_back(slices, t, n);
    for (auto& t : pool) t.join();
  }
  return vol;
}

namespace {

// Runs body(k) for k in [0, n) on `threads` threads (slices interleaved).
template <class Body>
void parallelSlices(std::int64_t n, int threads, Body&& body) {
  const int t = std::max(1, std::min<int>(resolveThreads(threads), static_cast<int>(std::max<std::int64_t>(n, 1))));
  if (t == 1) {
    for (std::int64_t k = 0; k < n; ++k) body(k);
    return;
  }
  std::vector<std::thread> pool;
  for (int i = 0; i < t; ++i)
    pool.emplace_back([&, i] {
      for (std::int64_t k = i; k < n; k += t) body(k);
    });
  for (auto& th : pool) th.join();
}

// Normalised taps (one per voxel, `spacing` mm apart) of a Gaussian of
// standard deviation sigma mm convolved with a box `box` mm wide, cut 3 sigma
// beyond the box.
std::vector<double> blurTaps(double sigma, double box, double spacing) {
  const double reach = 0.5 * box + 3.0 * sigma;
  const int r = static_cast<int>(std::floor(reach / spacing));
  std::vector<double> w(static_cast<std::size_t>(2 * r + 1));
  double sum = 0.0;
  for (int i = -r; i <= r; ++i) {
    const double x = i * spacing;
    double v = 0.0;
    if (box <= 0.0)
      v = sigma > 0.0 ? std::exp(-0.5 * x * x / (sigma * sigma)) : (i == 0 ? 1.0 : 0.0);
    else if (sigma <= 0.0)
      v = std::abs(x) <= 0.5 * box ? 1.0 : 0.0;
    else  // the Gaussian's mass over [x - box/2, x + box/2]
      v = std::erf((x + 0.5 * box) / (std::sqrt(2.0) * sigma)) - std::erf((x - 0.5 * box) / (std::sqrt(2.0) * sigma));
    w[static_cast<std::size_t>(i + r)] = v;
    sum += v;
  }
  for (double& v : w) v /= sum;
  return w;
}

}  // namespace

Volume expectedImageVolume(const Phantom& phantom, const BModeSimulator& bmode, const Grid& grid,
                           const Mat4& probeToReference, ScalarType type, int threads, std::uint64_t memoryLimitBytes) {
  // The power volume (double) and the output.
  checkGridFits(grid, 8 + static_cast<std::uint64_t>(scalarBytes(type)), "expected-image volume", memoryLimitBytes);
  const ProbeModel& probe = bmode.probe();
  // Which grid axis each probe axis runs along, and the probe face's depth origin.
  const Vec3 axes[3] = {glm::normalize(Vec3(probeToReference[0])), glm::normalize(Vec3(probeToReference[1])),
                        glm::normalize(Vec3(probeToReference[2]))};
  int gridAxis[3];
  for (int a = 0; a < 3; ++a) {
    const Vec3 c = glm::abs(axes[a]);
    gridAxis[a] = c.x >= c.y && c.x >= c.z ? 0 : (c.y >= c.z ? 1 : 2);
    if (c[gridAxis[a]] < std::cos(25.0 * 3.14159265358979323846 / 180.0))
      throw InputError(fmt::format("expected-image volume: the probe's {} axis is {:.0f} degrees from every grid axis; "
                                   "the expected image needs the probe's axes along the grid's",
                                   a == 0 ? "lateral" : a == 1 ? "axial" : "elevation",
                                   std::acos(c[gridAxis[a]]) * 180.0 / 3.14159265358979323846));
  }
  PP5_CHECK(gridAxis[0] != gridAxis[1] && gridAxis[1] != gridAxis[2] && gridAxis[0] != gridAxis[2]);
  const Vec3 face = transformPoint(probeToReference, Vec3(0.0));
  const int depthAxis = gridAxis[1];
  auto depthOf = [&](std::int64_t layer) {
    Vec3 v(0.0);
    v[depthAxis] = static_cast<double>(layer);
    return glm::dot(grid.voxelToWorld(v) - face, axes[1]);
  };

  // Backscatter power per voxel, the mean of 2 x 2 x 2 sub-samples where a
  // boundary may cross the voxel. Wires are line targets, imaged as coherent
  // reflectors rather than speckle (BModeSimulator), so they are left out: a
  // voxel a wire crosses expects the medium around it.
  std::vector<int> speckleBodies;
  for (std::size_t b = 0; b < phantom.bodies.size(); ++b)
    if (!phantom.bodies[b].lineTarget) speckleBodies.push_back(static_cast<int>(b));
  const std::size_t n = grid.voxelCount();
  std::vector<double> power(n, 0.0);
  std::array<double, kTissueCount> pw{};
  for (int t = 0; t < kTissueCount; ++t) pw[static_cast<std::size_t>(t)] = bmode.backscatterPower(static_cast<Tissue>(t));
  const double halfDiagonal = 0.5 * glm::length(grid.spacing);
  parallelSlices(grid.dims.z, threads, [&](std::int64_t k) {
    for (std::int64_t j = 0; j < grid.dims.y; ++j)
      for (std::int64_t i = 0; i < grid.dims.x; ++i) {
        const Vec3 p = grid.voxelToWorld(Vec3(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)));
        const Phantom::Sample s = phantom.sample(p, speckleBodies);
        double v = pw[static_cast<std::size_t>(s.tissue)];
        if (s.clearance < halfDiagonal) {
          v = 0.0;
          for (int c = 0; c < 8; ++c) {
            const Vec3 o((c & 1) ? 0.25 : -0.25, (c & 2) ? 0.25 : -0.25, (c & 4) ? 0.25 : -0.25);
            v += pw[static_cast<std::size_t>(phantom.sample(p + o * grid.spacing, speckleBodies).tissue)];
          }
          v /= 8.0;
        }
        power[grid.linear(i, j, k)] = v;
      }
  });

  // The intensity PSF: the amplitude PSF's sigma over sqrt(2) on each axis,
  // and along the depth the pixel's height too (a row averages its sub-rows'
  // envelopes over it). Columns are splatted linearly between neighbours,
  // a little more lateral blur.
  const double sx = probe.spacingX(), sy = probe.spacingY();
  auto tapsFor = [&](int probeAxis, double depth, double spacing) {
    switch (probeAxis) {
      case 0: {
        const double s = probe.lateralSigmaMm(depth);
        return blurTaps(std::sqrt(0.5 * s * s + sx * sx / 6.0), 0.0, spacing);
      }
      case 1: return blurTaps(std::sqrt(0.5) * probe.axialSigmaMm(), sy, spacing);
      default: return blurTaps(std::sqrt(0.5) * probe.elevationSigmaMm(depth), 0.0, spacing);
    }
  };

  // Separable blur along each probe axis's grid axis; the sigma of the
  // lateral and elevation passes follows the depth of the line.
  const Index3 d = grid.dims;
  const std::int64_t stride[3] = {1, d.x, d.x * d.y};
  std::vector<double> tmp(n);
  for (int pa = 0; pa < 3; ++pa) {
    const int ga = gridAxis[pa];
    const int o1 = (ga + 1) % 3, o2 = (ga + 2) % 3;  // the other two grid axes
    const std::int64_t len = d[ga];
    parallelSlices(d[o2], threads, [&](std::int64_t b) {
      std::vector<double> line(static_cast<std::size_t>(len));
      for (std::int64_t a = 0; a < d[o1]; ++a) {
        // The line's depth: its own coordinate on the depth axis (pa != 1).
        const std::int64_t depthLayer = o1 == depthAxis ? a : b;
        const std::size_t start = static_cast<std::size_t>(a * stride[o1] + b * stride[o2]);
        for (std::int64_t t = 0; t < len; ++t) line[static_cast<std::size_t>(t)] = power[start + static_cast<std::size_t>(t * stride[ga])];
        auto blurLine = [&](const std::vector<double>& taps, std::int64_t t) {
          const auto r = static_cast<std::int64_t>(taps.size() / 2);
          double sum = 0.0, wsum = 0.0;
          for (std::int64_t q = std::max<std::int64_t>(0, t - r); q <= std::min(len - 1, t + r); ++q) {
            const double w = taps[static_cast<std::size_t>(q - t + r)];
            sum += w * line[static_cast<std::size_t>(q)];
            wsum += w;
          }
          return sum / wsum;  // renormalised where the kernel leaves the grid
        };
        const auto taps = tapsFor(pa, pa == 1 ? 0.0 : depthOf(depthLayer), grid.spacing[ga]);
        for (std::int64_t t = 0; t < len; ++t) tmp[start + static_cast<std::size_t>(t * stride[ga])] = blurLine(taps, t);
      }
    });
    power.swap(tmp);
  }

  Volume vol;
  vol.allocate(grid, type);
  for (std::size_t i = 0; i < n; ++i) vol.setValue(i, bmode.expectedLevel(power[i]));
  return vol;
}

}  // namespace pp5::sim
