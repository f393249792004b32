#include "app/recon_run.hpp"

#include <chrono>
#include <cmath>

#include <spdlog/spdlog.h>

#include "core/error.hpp"

namespace pp5::app {

Grid chooseGrid(const PosedSequence& seq, const gp::ReconSettings& s, const Vec3& spacing, double marginMm,
                bool useConfigExtent) {
  const auto& vr = seq.config.volumeReconstruction;
  if (useConfigExtent && vr && vr->outputOrigin && vr->outputExtent) {
    const auto& e = *vr->outputExtent;
    Grid g;
    g.spacing = spacing;
    // Extent indices may start anywhere; voxel (e0, e2, e4) is the grid's first.
    g.origin = *vr->outputOrigin + Vec3(e[0], e[2], e[4]) * spacing;
    g.dims = Index3(e[1] - e[0] + 1, e[3] - e[2] + 1, e[5] - e[4] + 1);
    return g;
  }
  std::vector<Mat4> poses;
  for (const auto& p : seq.poses)
    if (p) poses.push_back(*p);
  const SequenceInfo& info = seq.reader->info();
  Grid g = gp::plusOutputGrid(poses, info.width, info.height, s, spacing);
  if (marginMm > 0.0) {
    const Index3 pad(std::llround(marginMm / spacing.x), std::llround(marginMm / spacing.y),
                     std::llround(marginMm / spacing.z));
    g.origin -= Vec3(pad) * spacing;
    g.dims += pad * Index3(2);
  }
  return g;
}

ReconRunStats runReconstruction(PosedSequence& seq, gp::Reconstructor& recon,
                                const std::function<bool(std::uint64_t)>& keep) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  auto lastReport = start;
  ReconRunStats st;
  const SequenceInfo& info = seq.reader->info();
  st.frames = info.frameCount;
  const int skip = std::max(1, recon.settings().skipInterval);
  Frame f;
  std::uint64_t i = 0;
  for (; seq.reader->next(f); ++i) {
    if (!seq.poses[i]) {
      ++st.skipped;
      continue;
    }
    if (i % static_cast<std::uint64_t>(skip) != 0 || (keep && !keep(i))) {
      ++st.notSelected;
      continue;
    }
    recon.insert(f, *seq.poses[i], f.timestamp);
    ++st.inserted;
    const auto now = Clock::now();
    if (now - lastReport > std::chrono::seconds(1)) {
      const double el = std::chrono::duration<double>(now - start).count();
      const double fps = static_cast<double>(i + 1) / el;
      spdlog::info("reconstruct: frame {}/{}, {:.1f} frames/s, {:.0f} s left", i + 1, info.frameCount, fps,
                   static_cast<double>(info.frameCount - i - 1) / fps);
      lastReport = now;
    }
  }
  if (i != info.frameCount) inputError(seq.path, "ended after {} of {} frames", i, info.frameCount);
  recon.finish();
  st.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  return st;
}

}  // namespace pp5::app
