#include "analysis/speckle_run.hpp"

#include <algorithm>
#include <cstdio>
#include <vector>

#include <spdlog/spdlog.h>

#include "core/error.hpp"

namespace pp5::gp {

SpeckleRun measureSpeckle(const PosedSequence& seq, const ReconSettings& rs, int maxPairs, int maxLag,
                          const std::function<bool(std::uint64_t)>& use) {
  const auto& info = seq.reader->info();
  const glm::dvec4 centre(0.5 * info.width, 0.5 * info.height, 0.0, 1.0);
  auto at = [&](std::uint64_t i) { return Vec3(*seq.poses[i] * centre); };
  // The frames used that can be placed, in order (as a reconstruction inserts
  // them, passing over the others); a pair is two neighbours in it.
  std::vector<std::uint64_t> used;
  for (std::uint64_t i = 0; i < seq.poses.size(); ++i)
    if (seq.poses[i] && (!use || use(i))) used.push_back(i);
  // Pair j (1 .. used.size() - 1) is used frames j - 1 and j.
  std::vector<double> steps;  // mm between the image centres, every pair
  for (std::size_t j = 1; j < used.size(); ++j) steps.push_back(glm::length(at(used[j]) - at(used[j - 1])));
  const std::size_t pairs = steps.size();
  if (pairs == 0)
    inputError(seq.path, "has no two consecutive frames that can both be placed: no speckle difference to measure");
  // At most maxPairs of them, spread evenly.
  const std::size_t want = std::min<std::size_t>(pairs, static_cast<std::size_t>(std::max(1, maxPairs)));
  std::vector<std::uint8_t> chosen(used.size(), 0);
  for (std::size_t k = 0; k < want; ++k) chosen[1 + k * pairs / want] = 1;

  SpeckleRun out;
  out.pairsAvailable = pairs;
  SpeckleCellMeter meter(maxLag);
  auto reader = SequenceReader::open(seq.path);
  Frame prev2, prev, cur;  // used frames j - 2, j - 1 and j
  FrameRuns runs(rs);
  std::size_t j = 0;  // the next used frame's place in `used`
  for (std::uint64_t i = 0; j < used.size() && reader->next(cur); ++i) {
    if (i != used[j]) continue;
    if (j >= 1 && chosen[j]) {
      if (meter.add(prev, cur, runs.of(cur)) && out.pixelMm.x == 0.0)
        out.pixelMm = {glm::length(Vec3((*seq.poses[i])[0])), glm::length(Vec3((*seq.poses[i])[1]))};
      // Along the sweep: this pair's first frame, with the frames on either side of it.
      if (j >= 2)
        meter.addTriple(prev2, prev, cur, glm::length(at(used[j - 1]) - at(used[j - 2])),
                        glm::length(at(i) - at(used[j - 2])), runs.of(cur));
    }
    std::swap(prev2, prev);
    std::swap(prev, cur);
    ++j;
  }
  out.cell = meter.result();
  const SpeckleCell& c = out.cell;
  if (c.pairs == 0)
    inputError(seq.path, "none of the {} pairs measured shows speckle inside the clip rectangle and fan (their "
               "differences are zero, or white noise): no resolution cell to measure", want);
  // About how many independent cells the estimate rests on (a cell spans
  // twice its half width each way): under a thousand, its half widths are
  // uncertain to tens of per cent (NwirePhantomFreehand's mostly black frames
  // leave about 50).
  const double cellPx = 4.0 * std::max(1.0, c.lateralPx.value_or(maxLag)) * std::max(1.0, c.axialPx.value_or(maxLag));
  out.independentCells = static_cast<double>(c.pixels) / cellPx;
  if (out.independentCells < 1000.0)
    spdlog::warn("speckle: only about {:.0f} independent speckle cells in {} pixels of {} pairs (the frames are "
                 "mostly dark or noise): the cell measured is uncertain", out.independentCells, c.pixels, c.pairs);
  std::nth_element(steps.begin(), steps.begin() + static_cast<std::ptrdiff_t>(steps.size() / 2), steps.end());
  out.frameSpacingMm = steps[steps.size() / 2];
  return out;
}

void deriveKernelFromFrames(const PosedSequence& seq, ReconSettings& rs, const ConfigSchema& schema,
                            const std::function<bool(std::uint64_t)>& use, glm::dvec2 insertedPixelScale) {
  if (!rs.tent.kernelFromFrames) return;
  checkReconSettings(rs);  // what the reconstruction would refuse, before the measurement
  // The frames the reconstruction is given: `use`'s, or every skip_interval-th.
  const auto skip = static_cast<std::uint64_t>(std::max(1, rs.skipInterval));
  const SpeckleRun m =
      measureSpeckle(seq, rs, 32, 64, use ? use : [skip](std::uint64_t i) { return i % skip == 0; });
  const glm::dvec2 inserted = m.pixelMm * insertedPixelScale;
  const auto k = kernelFromCell(m.cell, m.pixelMm.x, m.pixelMm.y, m.frameSpacingMm, inserted.x, inserted.y);
  if (!k)
    inputError(seq.path, "recon.kernel_from_frames: the speckle's {} half width is wider than 64 px, so no kernel can "
               "be derived from it; set recon.kernel_lateral_mm, recon.kernel_axial_mm and recon.kernel_elevation_mm",
               m.cell.lateralPx ? "axial" : "lateral");
  if (!(k->elevationMm >= 0.01))
    inputError(seq.path, "recon.kernel_from_frames: the frames' median spacing is {:.4f} mm (the probe hardly moved), "
               "so no reach along the sweep can be derived from it; set recon.kernel_elevation_mm", m.frameSpacingMm);
  // Within the range a file could give (a sparse leave-out can ask for more).
  constexpr double kMaxHalfWidthMm = 50.0;
  struct Width {
    const char* key;
    double* field;
    double derived;
  };
  const Width widths[] = {{"recon.kernel_lateral_mm", &rs.tent.kernelLateralMm, k->lateralMm},
                          {"recon.kernel_axial_mm", &rs.tent.kernelAxialMm, k->axialMm},
                          {"recon.kernel_elevation_mm", &rs.tent.kernelElevationMm, k->elevationMm}};
  std::printf("kernel from the frames: speckle half widths %.3f mm lateral, %.3f mm axial (%llu pairs, pixel "
              "%.4f x %.4f mm), frames %.3f mm apart (median)\n",
              *m.cell.lateralPx * m.pixelMm.x, *m.cell.axialPx * m.pixelMm.y,
              static_cast<unsigned long long>(m.cell.pairs), m.pixelMm.x, m.pixelMm.y, m.frameSpacingMm);
  if (insertedPixelScale != glm::dvec2(1.0))
    std::printf("  (the reconstruction is given pixels of %.4f x %.4f mm, after the subsampling)\n", inserted.x,
                inserted.y);
  for (const Width& w : widths) {
    if (schema.assigned(w.key)) {
      std::printf("  %-26s %.3f mm, as set (derived: %.3f)\n", w.key, *w.field, w.derived);
    } else if (w.derived > kMaxHalfWidthMm) {
      *w.field = kMaxHalfWidthMm;
      std::printf("  %-26s %.3f mm, derived %.3f mm and held to the option's largest value\n", w.key, kMaxHalfWidthMm,
                  w.derived);
    } else {
      *w.field = w.derived;
      std::printf("  %-26s %.3f mm, derived\n", w.key, w.derived);
    }
  }
  std::fflush(stdout);
}

}  // namespace pp5::gp
