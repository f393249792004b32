#pragma once
// A short doll sweep with small frames and its 2 mm grid, shared by the
// tests that run the serial pipeline over a sweep.
#include <vector>

#include "sim/simulate.hpp"

namespace pp5::test {

// 64x100-pixel frames 4 mm apart over 60 mm of the doll.
inline sim::SimSettings smallDollSweep() {
  sim::SimSettings ss;
  ss.phantom = sim::PhantomKind::Doll;
  ss.probe.widthPx = 64;
  ss.probe.heightPx = 100;
  ss.sweep.captureIntervalMm = 4.0;
  ss.sweep.lengthMm = 60.0;
  ss.threads = 2;
  return ss;
}

// Every frame's pose, and the 2 mm grid around them (2 mm of margin).
struct SweepGrid {
  std::vector<Mat4> poses;
  Grid grid;
};
inline SweepGrid sweepGrid(const sim::SweepSimulator& sim) {
  SweepGrid out;
  for (std::size_t i = 0; i < sim.frameCount(); ++i) out.poses.push_back(sim.imageToReference(i));
  out.grid = sim::fitGrid(out.poses, sim.probe().width, sim.probe().height, Vec3(2.0), 2.0);
  return out;
}

}  // namespace pp5::test
