#include "reconstruction/recon_run.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>

#include <spdlog/spdlog.h>

#include "core/config.hpp"
#include "core/error.hpp"

namespace pp5::gp {

void checkNoOutlierPose(const PosedSequence& seq) {
  // A pose far from all others (a tracker glitch) would stretch the automatic
  // extent to it, and the grid would then be refused for its size: name the
  // frame instead. Far: more than a metre from the middle of the frames'
  // centres, and twenty times farther than the frames typically lie from it.
  const SequenceInfo& info = seq.reader->info();
  std::vector<std::uint64_t> index;
  std::vector<Vec3> centre;
  for (std::size_t i = 0; i < seq.poses.size(); ++i)
    if (seq.poses[i]) {
      index.push_back(i);
      centre.push_back(transformPoint(*seq.poses[i], Vec3(0.5 * info.width, 0.5 * info.height, 0.0)));
    }
  if (centre.size() < 3) return;
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  Vec3 mid;
  for (int a = 0; a < 3; ++a) {
    std::vector<double> c;
    for (const Vec3& p : centre) c.push_back(p[a]);
    mid[a] = median(c);
  }
  std::vector<double> dist;
  for (const Vec3& p : centre) dist.push_back(glm::length(p - mid));
  const double typical = median(dist);
  const auto worst = static_cast<std::size_t>(std::max_element(dist.begin(), dist.end()) - dist.begin());
  const double d = dist[worst];
  if (!std::isfinite(d) || (d > 1000.0 && d > 20.0 * std::max(typical, 10.0)))
    inputError(seq.path,
               "frame {}: its image lies {:.4g} mm from the middle of the sweep, where the frames typically lie "
               "within {:.0f} mm: an outlier pose (a tracker glitch?) would stretch the grid to it; mark its "
               "transform INVALID or drop the frame",
               index[worst], d, typical);
}

Grid chooseGrid(const PosedSequence& seq, const ReconSettings& s, const Vec3& spacing, double marginMm,
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
  checkNoOutlierPose(seq);
  Grid g = plusOutputGrid(poses, info.width, info.height, s, spacing);
  if (marginMm > 0.0) {
    const Index3 pad(std::llround(marginMm / spacing.x), std::llround(marginMm / spacing.y),
                     std::llround(marginMm / spacing.z));
    g.origin -= Vec3(pad) * spacing;
    g.dims += pad * Index3(2);
  }
  return g;
}

Grid commandGrid(const PosedSequence& seq, const ReconSettings& s, const GridSettings* toml, const Vec3& plusSpacing) {
  if (!toml) return chooseGrid(seq, s, plusSpacing, 0.0, true);
  return toml->autoExtent ? chooseGrid(seq, s, toml->spacing, toml->marginMm, false) : toml->fixedGrid();
}

ReconRunStats runReconstruction(PosedSequence& seq, Reconstructor& recon,
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

Grid GridSettings::fixedGrid() const {
  Grid g;
  g.origin = origin;
  g.spacing = spacing;
  g.dims = Index3(dims);
  return g;
}

void registerOptions(ConfigSchema& schema, GridSettings& s) {
  schema.section("grid", "The reconstruction grid, which is also the grid of the simulated truth volume. "
                         "`reconstruct` and `evaluate leave-out` with TOML settings use it; with a PLUS config alone, "
                         "its OutputSpacing (and OutputOrigin and OutputExtent, where it gives both); `evaluate "
                         "truth` reconstructs on the truth volume's grid.");
  schema.option("grid.auto_extent", &s.autoExtent, true,
                "Fit the grid around every frame's corners (PLUS's rule), plus `grid.margin_mm`; "
                "otherwise use `grid.origin` and `grid.dims`.");
  schema.option("grid.origin", &s.origin, {0.0, 0.0, 0.0}, -1e6, 1e6,
                "Centre of voxel (0,0,0) in mm, in the Reference frame (when `auto_extent = false`).");
  schema.option("grid.spacing", &s.spacing, {1.0, 1.0, 1.0}, 1e-3, 100.0, "Voxel size in mm along x, y, z.");
  schema.option("grid.dims", &s.dims, {256, 256, 256}, 1, 100000,
                "Voxels along x, y, z (when `auto_extent = false`).");
  schema.option("grid.margin_mm", &s.marginMm, 2.0, 0.0, 1000.0,
                "Margin added on every side of an automatic extent, in mm.");
  schema.option("grid.memory_limit_gib", &s.memoryLimitGiB, 0.0, 0.0, 1e6,
                "Largest grid memory allowed, in GiB; 0 means the memory the machine has available. "
                "A grid over the limit is refused before anything is allocated.");
}

}  // namespace pp5::gp
