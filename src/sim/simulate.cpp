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

}  // namespace pp5::sim
