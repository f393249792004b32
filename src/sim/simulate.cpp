#include "sim/simulate.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <limits>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

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
    : settings_(s), phantom_(makePhantom(std::string(enumName(s.phantom)))), probe_(makeProbe(s.probe)) {
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

// The cumulative distribution of the axial intensity PSF: a Gaussian of
// standard deviation sigma convolved with a box `box` mm wide (the pixel's
// height), i.e. the fraction of the kernel's mass below t. With
// J(s) = integral of Phi(u / sigma) du up to s = s Phi(s / sigma) + sigma phi(s / sigma),
// it is (J(t + box/2) - J(t - box/2)) / box.
double axialCdf(double t, double sigma, double box) {
  constexpr double kInvSqrt2 = 0.70710678118654752440;
  constexpr double kInvSqrt2Pi = 0.39894228040143267794;
  auto Phi = [&](double s) { return 0.5 * std::erfc(-s * kInvSqrt2); };
  if (box <= 1e-4 * sigma) return Phi(t / sigma);
  if (sigma <= 1e-4 * box) return std::clamp(t / box + 0.5, 0.0, 1.0);
  auto J = [&](double s) { return s * Phi(s / sigma) + sigma * kInvSqrt2Pi * std::exp(-0.5 * (s / sigma) * (s / sigma)); };
  return std::clamp((J(t + 0.5 * box) - J(t - 0.5 * box)) / box, 0.0, 1.0);
}

// The backscatter power along the line p0 + t * dir, t in [t0, t1], through
// the speckle bodies: its value at t0 and, at every boundary, (t, power after
// minus power before), found as the B-mode model's beam tracer finds them
// (its minimum step) but placed to 1e-6 mm.
struct PowerSteps {
  double start = 0.0;
  std::vector<std::pair<double, double>> steps;
};
void tracePower(const Phantom& phantom, const std::vector<int>& bodies, const std::array<double, kTissueCount>& pw,
                const Vec3& p0, const Vec3& dir, double t0, double t1, PowerSteps& out) {
  constexpr double kMinStepMm = 0.02, kBoundaryTolMm = 1e-6;
  auto powerOf = [&](Tissue t) { return pw[static_cast<std::size_t>(t)]; };
  out.steps.clear();
  out.start = powerOf(phantom.sample(p0 + t0 * dir, bodies).tissue);
  phantom.traceBoundaries(p0, dir, t0, t1, bodies, kMinStepMm, kBoundaryTolMm,
                          [&](double tb, const Phantom::Sample& before, const Phantom::Sample& after) {
                            const double dp = powerOf(after.tissue) - powerOf(before.tissue);
                            if (dp != 0.0) out.steps.emplace_back(tb, dp);
                          });
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

  // The frames show the backscatter power of the tissue in their own plane
  // (the elevation beam shapes the speckle, not the tissue map: the B-mode
  // model scales each scatterer by the tissue on the image plane), blurred
  // by the intensity PSF in the plane: the amplitude PSF's sigma over sqrt(2)
  // laterally (plus the columns' linear splat) and along the pulse, with the
  // pixel's height (a row averages its sub-rows' envelopes). So each voxel
  // gets that blurred power at its centre, evaluated as a point value (not
  // sampled on the grid, which at 1 mm would alias a 0.2 mm pulse):
  //  - along the depth, exactly: the line through the centre is traced to
  //    its tissue boundaries, and each boundary's step is blurred by the
  //    axial PSF's closed-form distribution;
  //  - laterally, by quadrature over lines `fine` per voxel (a pitch of at
  //    most an eighth of the lateral sigma, up to 32 lines per voxel),
  //    Gaussian weights normalised;
  //  - no blur across the elevation: voxels on one grid plane along it are
  //    computed from that plane alone.
  // Wires are line targets, imaged as coherent reflectors rather than
  // speckle (BModeSimulator), so they are left out: a voxel a wire crosses
  // expects the medium around it.
  std::vector<int> speckleBodies;
  for (std::size_t b = 0; b < phantom.bodies.size(); ++b)
    if (!phantom.bodies[b].lineTarget) speckleBodies.push_back(static_cast<int>(b));
  std::array<double, kTissueCount> pw{};
  for (int t = 0; t < kTissueCount; ++t) pw[static_cast<std::size_t>(t)] = bmode.backscatterPower(static_cast<Tissue>(t));

  const int latAxis = gridAxis[0], elAxis = gridAxis[2];
  const Index3 d = grid.dims;
  const std::int64_t nLat = d[latAxis], nDepth = d[depthAxis], nEl = d[elAxis];
  const double sLat = grid.spacing[latAxis], sDepth = grid.spacing[depthAxis];
  const double sx = probe.spacingX(), sy = probe.spacingY();
  const double sigmaAx = std::sqrt(0.5) * probe.axialSigmaMm();
  const double axialReach = 0.5 * sy + 7.0 * sigmaAx;  // beyond it the distribution is 0 or 1 (to double)
  std::vector<double> sigmaLat(static_cast<std::size_t>(nDepth));
  double sigmaLatMin = std::numeric_limits<double>::infinity(), sigmaLatMax = 0.0;
  for (std::int64_t k = 0; k < nDepth; ++k) {
    const double s = probe.lateralSigmaMm(std::max(0.0, depthOf(k)));
    const double v = std::sqrt(0.5 * s * s + sx * sx / 6.0);
    sigmaLat[static_cast<std::size_t>(k)] = v;
    sigmaLatMin = std::min(sigmaLatMin, v);
    sigmaLatMax = std::max(sigmaLatMax, v);
  }
  const int fine = std::clamp(static_cast<int>(std::ceil(sLat / (0.125 * sigmaLatMin))), 1, 32);
  const double pitch = sLat / fine;
  const auto pad = static_cast<std::int64_t>(std::ceil(4.0 * sigmaLatMax / sLat)) + 1;  // voxels of lines beyond each side
  const std::int64_t lines = (nLat + 2 * pad) * fine;
  const auto reachLines = static_cast<std::int64_t>(std::ceil(4.0 * sigmaLatMax / pitch));
  // Lateral weights per depth layer: line q (0..lines) sits at lateral voxel
  // coordinate (q + 0.5) / fine - 0.5 - pad; voxel L's `taps` weights run
  // over the lines from L * fine + firstTapLine0 on, at firstOffset ..
  // -firstOffset pitches from its centre (whole pitches for an odd `fine`,
  // half pitches for an even one), the same for every L.
  const std::int64_t taps = 2 * reachLines + (fine % 2 == 0 ? 2 : 1);
  const double firstOffset = -static_cast<double>(reachLines) - (fine % 2 == 0 ? 0.5 : 0.0);  // pitches
  std::vector<double> weights(static_cast<std::size_t>(nDepth * taps));
  for (std::int64_t k = 0; k < nDepth; ++k) {
    double* w = &weights[static_cast<std::size_t>(k * taps)];
    double sum = 0.0;
    const double sg = sigmaLat[static_cast<std::size_t>(k)];
    for (std::int64_t q = 0; q < taps; ++q) {
      const double x = (firstOffset + static_cast<double>(q)) * pitch;
      w[q] = std::exp(-0.5 * x * x / (sg * sg));
      sum += w[q];
    }
    for (std::int64_t q = 0; q < taps; ++q) w[q] /= sum;
  }
  const std::int64_t firstTapLine0 = pad * fine + (fine - 1) / 2 - reachLines;

  const std::size_t n = grid.voxelCount();
  std::vector<double> power(n, 0.0);
  Vec3 depthStep(0.0);
  depthStep[depthAxis] = 1.0;
  const Vec3 dir = glm::normalize(grid.voxelToWorld(depthStep) - grid.voxelToWorld(Vec3(0.0)));
  const double tEnd = static_cast<double>(nDepth - 1) * sDepth;  // the last layer, along the line
  parallelSlices(nEl, threads, [&](std::int64_t e) {
    std::vector<double> blurred(static_cast<std::size_t>(lines * nDepth));  // [line][depth]
    PowerSteps steps;
    for (std::int64_t q = 0; q < lines; ++q) {
      Vec3 v(0.0);
      v[elAxis] = static_cast<double>(e);
      v[latAxis] = (static_cast<double>(q) + 0.5) / fine - 0.5 - static_cast<double>(pad);
      tracePower(phantom, speckleBodies, pw, grid.voxelToWorld(v), dir, -axialReach, tEnd + axialReach, steps);
      double* out = &blurred[static_cast<std::size_t>(q * nDepth)];
      std::fill_n(out, nDepth, steps.start);
      for (const auto& [tb, dp] : steps.steps) {
        // Layers whose centre lies farther than the reach below the boundary get the whole step.
        const auto k0 = std::max<std::int64_t>(0, static_cast<std::int64_t>(std::ceil((tb - axialReach) / sDepth)));
        const auto k1 = std::min<std::int64_t>(nDepth - 1, static_cast<std::int64_t>(std::floor((tb + axialReach) / sDepth)));
        for (std::int64_t k = k0; k <= k1; ++k)
          out[k] += dp * axialCdf(static_cast<double>(k) * sDepth - tb, sigmaAx, sy);
        for (std::int64_t k = std::max<std::int64_t>(k1 + 1, 0); k < nDepth; ++k) out[k] += dp;
      }
    }
    Index3 idx(0);
    idx[elAxis] = e;
    for (std::int64_t L = 0; L < nLat; ++L) {
      idx[latAxis] = L;
      const std::int64_t first = L * fine + firstTapLine0;
      for (std::int64_t k = 0; k < nDepth; ++k) {
        const double* w = &weights[static_cast<std::size_t>(k * taps)];
        double sum = 0.0;
        for (std::int64_t q = 0; q < taps; ++q) sum += w[q] * blurred[static_cast<std::size_t>((first + q) * nDepth + k)];
        idx[depthAxis] = k;
        power[grid.linear(idx.x, idx.y, idx.z)] = std::max(sum, 0.0);  // steps summed in water can leave -1e-17
      }
    }
  });

  Volume vol;
  vol.allocate(grid, type);
  for (std::size_t i = 0; i < n; ++i) vol.setValue(i, bmode.expectedLevel(power[i]));
  return vol;
}

}  // namespace pp5::sim
