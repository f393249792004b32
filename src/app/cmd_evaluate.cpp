// `pp5echo evaluate truth|leave-out|speckle ...`: reconstruction accuracy, and
// the resolution cell that a recording's frames show.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "core/threads.hpp"
#include "reconstruction/kernels.hpp"
#include "app/commands.hpp"
#include "reconstruction/recon_run.hpp"
#include "reconstruction/slice_geometry.hpp"
#include "app/settings.hpp"
#include "analysis/speckle_run.hpp"
#include "core/error.hpp"
#include "formats/volume_io.hpp"
#include "analysis/evaluation.hpp"
#include "analysis/speckle_cell.hpp"

namespace pp5::app {

namespace {

struct CommonOpts {
  std::string sequence, plusConfig, config, json;
  std::vector<std::string> overrides;
  int threads = -1;
};

void addCommon(CLI::App* cmd, CommonOpts& o) {
  cmd->add_option("SEQUENCE", o.sequence, "PLUS sequence")->required();
  cmd->add_option("--plus-config", o.plusConfig, "PLUS device-set XML (calibration; settings unless --config)")
      ->required();
  cmd->add_option("-c,--config", o.config, "TOML settings ([recon], [grid])");
  cmd->add_option("--set", o.overrides, "Override a TOML option: key=value (repeatable)");
  cmd->add_option("--threads", o.threads, "Threads (0 = every core)")->check(CLI::Range(0, kMaxThreads));
  cmd->add_option("--json", o.json, "Also write the results as JSON to this file ('-' = standard output)");
}

// Reconstruction settings: TOML when given, else the PLUS config's element.
// With recon.kernel_from_frames and `derive`, the kernel is derived from the
// frames `use` selects (those the reconstruction is given).
bool tomlSettings(const CommonOpts& o) { return !o.config.empty() || !o.overrides.empty(); }

gp::ReconSettings reconSettings(const CommonOpts& o, const PosedSequence& seq, Settings& s, Vec3* plusSpacing,
                                const std::function<bool(std::uint64_t)>& use = {}, bool derive = true) {
  gp::ReconSettings rs;
  if (tomlSettings(o)) {
    ConfigSchema schema;
    registerAll(schema, s);
    loadSettings(schema, o.config, o.overrides);
    rs = s.recon;
    if (derive) deriveKernelFromFrames(seq, rs, schema, use);
  } else {
    if (!seq.config.volumeReconstruction)
      inputError(o.plusConfig, "has no VolumeReconstruction element; give the settings with --config");
    rs = gp::fromPlus(*seq.config.volumeReconstruction);
    *plusSpacing = seq.config.volumeReconstruction->outputSpacing;
  }
  if (o.threads >= 0) rs.threads = o.threads;
  return rs;
}

// The tent kernel the reconstruction used (set, or derived from the frames).
void addKernel(nlohmann::ordered_json& j, const gp::ReconSettings& rs) {
  if (!gp::kernelFor(rs.method).tentKernel) return;
  j["kernel_mm"] = {rs.tent.kernelLateralMm, rs.tent.kernelAxialMm, rs.tent.kernelElevationMm};
  j["kernel_from_frames"] = rs.tent.kernelFromFrames;
}

void emitJson(const std::string& where, const nlohmann::ordered_json& j) {
  if (where.empty()) return;
  if (where == "-") {
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::ofstream out(where);
  if (!out) throw InputError(where + ": cannot write the JSON results");
  out << j.dump(2) << "\n";
}

std::string describe(const gp::ReconSettings& rs) {
  std::string d = gp::kernelFor(rs.method).describe(rs);
  if (rs.pixel.fillHoles) d += "+holes";
  return d + " (" + std::string(enumName(rs.arithmetic)) + ")";
}

}  // namespace

void addEvaluateCommand(CLI::App& app, int& exitCode) {
  auto* eval = app.add_subcommand(
      "evaluate", "Measure reconstruction accuracy (ground truth or leave-out), or a recording's speckle");
  eval->require_subcommand(1);

  // --- ground truth ---
  struct TruthOpts : CommonOpts {
    std::string truth;
    std::string volume;
  };
  auto t = std::make_shared<TruthOpts>();
  auto* truth = eval->add_subcommand("truth", "Reconstruct on the truth volume's grid and compare voxel by voxel");
  addCommon(truth, *t);
  truth->add_option("--truth", t->truth, "Ground-truth volume (from `pp5echo simulate`)")->required();
  truth->add_option("-o,--volume", t->volume, "Also write the reconstruction that was compared (.mha/.nrrd, float32)");
  truth->callback([t, &exitCode] {
    PosedSequence seq = openPosedSequence(t->sequence, t->plusConfig);
    Settings s;
    Vec3 plusSpacing;  // not used: the truth's grid
    const gp::ReconSettings rs = reconSettings(*t, seq, s, &plusSpacing);
    const Volume truthVol = readVolume(t->truth);
    std::uint64_t notFinite = 0;
    for (std::size_t i = 0; i < truthVol.grid.voxelCount(); ++i) notFinite += std::isfinite(truthVol.value(i)) ? 0 : 1;
    if (notFinite > 0)
      inputError(t->truth, "holds {} voxels that are not finite numbers (NaN or infinity): no error can be measured "
                 "against it", notFinite);
    // On the truth's grid ([grid]'s extent and spacing do not apply), within [grid]'s memory limit.
    auto recon = gp::makeReconstructor(truthVol.grid, rs, tomlSettings(*t) ? s.grid.memoryLimitBytes() : 0, t->truth);
    const gp::ReconRunStats st = runReconstruction(seq, *recon);
    std::vector<Mat4> poses;
    for (const auto& p : seq.poses)
      if (p) poses.push_back(*p);
    const auto swept = gp::sweptRegion(truthVol.grid, poses, seq.reader->info().width, seq.reader->info().height);
    const auto cov = [&](std::size_t i) { return recon->hasValue(i); };
    const gp::TruthMetrics m = gp::compareWithTruth(recon->output(), cov, truthVol, swept);
    // An error over nothing is no score, least of all a perfect one.
    if (m.compared == 0)
      inputError(t->truth, "no voxel of its grid is both swept and reconstructed ({} hold a value, {} are swept): "
                 "nothing to compare; is the truth volume where the sweep is?", m.covered, m.swept);
    std::printf("ground truth: %s\n", t->truth.c_str());
    std::printf("  method            %s\n", describe(rs).c_str());
    std::printf("  frames            %llu inserted, %llu skipped\n", static_cast<unsigned long long>(st.inserted),
                static_cast<unsigned long long>(st.skipped));
    std::printf("  RMSE              %.3f grey levels (the %llu swept voxels with a value)\n", m.rmse,
                static_cast<unsigned long long>(m.compared));
    std::printf("  MAE               %.3f grey levels\n", m.mae);
    std::printf("  bias              %+.3f grey levels (mean of reconstruction - truth)\n", m.bias);
    std::printf("  PSNR              %.2f dB\n", m.psnrDb);
    std::printf("  RMSE, tissue      %.3f grey levels (the %llu of them brighter than the background)\n",
                m.rmseTissue, static_cast<unsigned long long>(m.tissueCompared));
    std::printf("  MAE, tissue       %.3f grey levels\n", m.maeTissue);
    std::printf("  bias, tissue      %+.3f grey levels\n", m.biasTissue);
    std::printf("  RMSE, edge        %.3f grey levels, bias %+.3f (the %llu background voxels within %g mm of tissue)\n",
                m.rmseEdge, m.biasEdge, static_cast<unsigned long long>(m.edgeCompared), m.edgeMm);
    std::printf("  RMSE, far         %.3f grey levels (the %llu other background voxels)\n", m.rmseFar,
                static_cast<unsigned long long>(m.farCompared));
    std::printf("  coverage          %.4f of %llu voxels\n", m.coverage(), static_cast<unsigned long long>(m.voxels));
    std::printf("  holes in sweep    %.5f (%llu of %llu swept voxels)\n", m.holeFraction(),
                static_cast<unsigned long long>(m.sweptHoles), static_cast<unsigned long long>(m.swept));
    nlohmann::ordered_json j;
    j["protocol"] = "truth";
    j["sequence"] = t->sequence;
    j["truth"] = t->truth;
    j["method"] = describe(rs);
    addKernel(j, rs);
    j["frames_inserted"] = st.inserted;
    j["frames_skipped"] = st.skipped;
    j["rmse"] = m.rmse;
    j["mae"] = m.mae;
    j["bias"] = m.bias;
    j["psnr_db"] = m.psnrDb;
    j["voxels_compared"] = m.compared;
    j["rmse_tissue"] = m.rmseTissue;
    j["mae_tissue"] = m.maeTissue;
    j["bias_tissue"] = m.biasTissue;
    j["tissue_voxels_compared"] = m.tissueCompared;
    j["edge_mm"] = m.edgeMm;
    j["rmse_edge"] = m.rmseEdge;
    j["bias_edge"] = m.biasEdge;
    j["edge_voxels_compared"] = m.edgeCompared;
    j["rmse_far"] = m.rmseFar;
    j["far_voxels_compared"] = m.farCompared;
    j["coverage"] = m.coverage();
    j["voxels"] = m.voxels;
    j["swept_voxels"] = m.swept;
    j["swept_holes"] = m.sweptHoles;
    j["hole_fraction"] = m.holeFraction();
    emitJson(t->json, j);
    if (!t->volume.empty()) writeVolume(t->volume, recon->output().as(ScalarType::F32));
    exitCode = 0;
  });

  // --- leave-out ---
  struct LeaveOpts : CommonOpts {
    int keepEvery = 2;
    std::string reading = "trilinear";
    bool heldOutInVolume = false;
  };
  auto l = std::make_shared<LeaveOpts>();
  auto* leave = eval->add_subcommand(
      "leave-out", "Rohling, Gee & Berman 1999: reconstruct from every k-th frame, compare with the held-out frames");
  addCommon(leave, *l);
  leave->add_option("--keep-every", l->keepEvery, "Keep every k-th frame: 2 removes 50%, 4 removes 75%")
      ->check(CLI::Range(2, 1000));
  leave->add_option("--reading", l->reading,
                    "How a held-out pixel is read from the volume: trilinear (where all 8 neighbours hold a value) or "
                    "plus (as PLUS's volume is read: the trilinear value rounded to a grey level, and a pixel whose "
                    "value is 0 not compared; docs/quality.md)")
      ->check(CLI::IsMember({"trilinear", "plus"}));
  leave->add_flag("--held-out-in-volume", l->heldOutInVolume,
                  "Insert the held-out frames too, and still score them: not a leave-out, but what the grid holds "
                  "of those frames when it is given them, to set a leave-out against (docs/quality.md)");
  leave->callback([l, &exitCode] {
    const gp::LeaveOutReading reading =
        l->reading == "plus" ? gp::LeaveOutReading::PlusGreyLevels : gp::LeaveOutReading::Trilinear;
    PosedSequence seq = openPosedSequence(l->sequence, l->plusConfig);
    // Every pose is checked as `reconstruct` checks the frames it inserts, the
    // held-out ones too: a singular pose would be scored (and stretch the
    // grid to reach it) where `reconstruct` refuses it.
    for (std::size_t i = 0; i < seq.poses.size(); ++i)
      if (seq.poses[i]) (void)gp::poseFromMatrix(*seq.poses[i], fmt::format("{}: frame {}", l->sequence, i));
    Settings s;
    Vec3 plusSpacing;
    const auto k = static_cast<std::uint64_t>(l->keepEvery);
    const auto inserted = [k, every = l->heldOutInVolume](std::uint64_t i) { return every || i % k == 0; };
    gp::ReconSettings rs = reconSettings(*l, seq, s, &plusSpacing, inserted);
    // The leave-out stride replaces SkipInterval: every frame not kept is held out.
    if (rs.skipInterval > 1)
      spdlog::warn("evaluate leave-out: --keep-every {} replaces recon.skip_interval = {} (SkipInterval)", k,
                   rs.skipInterval);
    rs.skipInterval = 1;
    // The grid as `reconstruct` chooses it: TOML's [grid] where given, else the PLUS config's extent or PLUS's rule.
    const bool useToml = tomlSettings(*l);
    const Grid grid = commandGrid(seq, rs, useToml ? &s.grid : nullptr, plusSpacing);
    auto recon = gp::makeReconstructor(grid, rs, useToml ? s.grid.memoryLimitBytes() : 0,
                                       useToml && !l->config.empty() ? l->config : l->plusConfig);
    const gp::ReconRunStats st = runReconstruction(seq, *recon, inserted);

    // Second pass over the file for the held-out frames.
    auto reader = SequenceReader::open(l->sequence);
    const auto cov = [&](std::size_t i) { return recon->hasValue(i); };
    gp::LeaveOutMetrics m;
    Frame f;
    gp::FrameRuns runs(rs);
    for (std::uint64_t i = 0; reader->next(f); ++i) {
      if (i % k == 0 || !seq.poses[i]) continue;
      gp::compareHeldOutFrame(recon->output(), cov, f, *seq.poses[i], runs.of(f), m, reading);
    }
    m.finish();
    if (m.framesHeldOut == 0) inputError(l->sequence, "has no placeable frame to hold out with --keep-every {}", k);
    if (m.pixelsCompared == 0)
      inputError(l->sequence, "no pixel of the {} held-out frames has a value all around it in the volume ({} skipped): "
                 "nothing to compare; keep more frames (--keep-every) or use a method that fills between them",
                 m.framesHeldOut, m.pixelsSkipped);

    std::printf("leave-out: %s, keep every %llu%s frame (%.0f%% removed)\n", l->sequence.c_str(),
                static_cast<unsigned long long>(k), k == 2 ? "nd" : "th", 100.0 * (1.0 - 1.0 / static_cast<double>(k)));
    std::printf("  method            %s\n", describe(rs).c_str());
    std::printf("  reading           %s\n", l->reading.c_str());
    std::printf("  grid              %lldx%lldx%lld voxels of %g x %g x %g mm, origin %g %g %g mm\n",
                static_cast<long long>(grid.dims.x), static_cast<long long>(grid.dims.y),
                static_cast<long long>(grid.dims.z), grid.spacing.x, grid.spacing.y, grid.spacing.z, grid.origin.x,
                grid.origin.y, grid.origin.z);
    if (l->heldOutInVolume)
      std::printf("  held-out frames   inserted too (--held-out-in-volume): what the grid holds of them, not a leave-out\n");
    std::printf(l->heldOutInVolume ? "  frames            %llu inserted, %llu of them scored, %llu skipped\n"
                                   : "  frames            %llu kept, %llu held out, %llu skipped\n",
                static_cast<unsigned long long>(st.inserted), static_cast<unsigned long long>(m.framesHeldOut),
                static_cast<unsigned long long>(st.skipped));
    const double compared = static_cast<double>(m.pixelsCompared) /
                            static_cast<double>(std::max<std::uint64_t>(1, m.pixelsCompared + m.pixelsSkipped));
    std::printf("  MAE               %.3f grey levels (%.1f%% of pixels compared)\n", m.mae, 100.0 * compared);
    std::printf("  bias              %+.3f grey levels (mean of volume - held-out pixel)\n", m.bias);
    std::printf("  RMSE              %.3f grey levels (%.1f%% of pixels compared)\n", m.rmse, 100.0 * compared);
    std::printf("  pixels compared   %llu (%.1f%%)\n", static_cast<unsigned long long>(m.pixelsCompared),
                100.0 * compared);
    std::printf("  pixels skipped    %llu (no value in the volume there%s)\n",
                static_cast<unsigned long long>(m.pixelsSkipped),
                reading == gp::LeaveOutReading::PlusGreyLevels ? ", or a value that rounds to 0" : "");
    std::printf("  (pixels inside the clip rectangle and fan only)\n");
    nlohmann::ordered_json j;
    j["protocol"] = "leave-out";
    j["sequence"] = l->sequence;
    j["method"] = describe(rs);
    addKernel(j, rs);
    j["reading"] = l->reading;
    j["held_out_in_volume"] = l->heldOutInVolume;
    j["keep_every"] = k;
    j["grid"] = {{"dims", {grid.dims.x, grid.dims.y, grid.dims.z}},
                 {"spacing_mm", {grid.spacing.x, grid.spacing.y, grid.spacing.z}},
                 {"origin_mm", {grid.origin.x, grid.origin.y, grid.origin.z}}};
    j["frames_kept"] = st.inserted;
    j["frames_held_out"] = m.framesHeldOut;
    j["mae"] = m.mae;
    j["bias"] = m.bias;
    j["rmse"] = m.rmse;
    j["pixels_compared"] = m.pixelsCompared;
    j["pixels_skipped"] = m.pixelsSkipped;
    j["compared_fraction"] = compared;
    emitJson(l->json, j);
    exitCode = 0;
  });

  // The resolution cell the frames show (analysis/speckle_cell.hpp).
  struct SpeckleOpts : CommonOpts {
    int maxPairs = 32;
    int maxLag = 64;
  };
  auto sp = std::make_shared<SpeckleOpts>();
  auto* speckle = eval->add_subcommand(
      "speckle", "Measure the probe's resolution cell, in plane and along the sweep, from the speckle of consecutive "
      "frames, and suggest a tent kernel");
  addCommon(speckle, *sp);
  speckle->add_option("--max-pairs", sp->maxPairs, "Measure at most this many pairs, spread over the recording")
      ->check(CLI::Range(1, 100000));
  speckle->add_option("--max-lag", sp->maxLag, "Largest lag of the autocorrelation, pixels")->check(CLI::Range(2, 1024));
  speckle->callback([sp, &exitCode] {
    PosedSequence seq = openPosedSequence(sp->sequence, sp->plusConfig);
    Settings s;
    Vec3 plusSpacing;  // not used
    // The clip rectangle and fan only: this command measures the cell itself.
    const gp::ReconSettings rs = reconSettings(*sp, seq, s, &plusSpacing, {}, false);
    const gp::SpeckleRun m = measureSpeckle(seq, rs, sp->maxPairs, sp->maxLag);
    const gp::SpeckleCell& c = m.cell;
    const glm::dvec2 pixelMm = m.pixelMm;
    const double step = m.frameSpacingMm;
    const double cells = m.independentCells;

    std::printf("speckle: %s\n", sp->sequence.c_str());
    std::printf("  pairs             %llu measured of %zu pairs of consecutive placed frames\n",
                static_cast<unsigned long long>(c.pairs), m.pairsAvailable);
    std::printf("  pixel             %.4f x %.4f mm\n", pixelMm.x, pixelMm.y);
    auto line = [&](const char* what, const std::optional<double>& px, double mmPerPx) {
      if (px)
        std::printf("  %-17s %.3f mm (%.2f px)%s\n", what, *px * mmPerPx, *px,
                    *px < 1.0 ? "  under a pixel: the images sample the speckle too coarsely to measure it here" : "");
      else
        std::printf("  %-17s wider than %d px (the largest lag measured, --max-lag)\n", what, sp->maxLag);
    };
    line("lateral (x)", c.lateralPx, pixelMm.x);
    line("axial (y)", c.axialPx, pixelMm.y);
    std::printf("  (half width at half maximum of the autocorrelation of the frames' differences, over the %llu "
                "pixels of speckle: inside, non-zero in both frames, in blocks that are not white noise)\n",
                static_cast<unsigned long long>(c.pixels));
    switch (c.elevation) {
      case gp::SpeckleCell::Elevation::Measured:
        std::printf("  elevation         %.3f mm (from %llu triples of consecutive frames: the speckle's decorrelation "
                    "over %.3f and %.3f mm, variance ratio %.3f)\n"
                    "  (a probe that turns as it moves reads short here: the image centres' distance is not the "
                    "distance along the beam)\n",
                    *c.elevationMm, static_cast<unsigned long long>(c.triples), c.nearMm, c.farMm, c.varianceRatio);
        break;
      case gp::SpeckleCell::Elevation::Decorrelated:
      case gp::SpeckleCell::Elevation::Correlated:
        std::printf("  elevation         not measured: over %llu triples of consecutive frames the variance ratio is "
                    "%.3f, too near %s (the frames are %s)\n",
                    static_cast<unsigned long long>(c.triples), c.varianceRatio,
                    c.elevation == gp::SpeckleCell::Elevation::Decorrelated ? "1 to read" : "its top to read",
                    c.elevation == gp::SpeckleCell::Elevation::Decorrelated
                        ? "farther apart than their speckle stays correlated"
                        : "too close for their speckle to decorrelate");
        break;
      case gp::SpeckleCell::Elevation::NoTriple:
        std::printf("  elevation         not measured: no three consecutive frames with speckle\n");
        break;
    }
    std::printf("  frame spacing     %.3f mm (median distance between consecutive image centres)\n", step);
    const auto kernel = gp::kernelFromCell(c, pixelMm.x, pixelMm.y, step);
    if (kernel)
      std::printf("  tent kernel       --set recon.kernel_lateral_mm=%.2f --set recon.kernel_axial_mm=%.2f "
                  "--set recon.kernel_elevation_mm=%.2f\n"
                  "                    (a suggestion: scaled from this cell and spacing as the default is from the "
                  "simulated paper35 probe's; docs/quality.md)\n",
                  kernel->lateralMm, kernel->axialMm, kernel->elevationMm);
    nlohmann::ordered_json j;
    j["protocol"] = "speckle";
    j["sequence"] = sp->sequence;
    j["pairs"] = c.pairs;
    j["pixels"] = c.pixels;
    j["pixel_mm"] = {pixelMm.x, pixelMm.y};
    auto opt = [](const std::optional<double>& v, double k) {
      return v ? nlohmann::ordered_json(*v * k) : nlohmann::ordered_json(nullptr);
    };
    j["lateral_px"] = opt(c.lateralPx, 1.0);
    j["axial_px"] = opt(c.axialPx, 1.0);
    j["lateral_mm"] = opt(c.lateralPx, pixelMm.x);
    j["axial_mm"] = opt(c.axialPx, pixelMm.y);
    j["frame_spacing_mm"] = step;
    j["elevation_mm"] = opt(c.elevationMm, 1.0);
    j["triples"] = c.triples;
    j["elevation_variance_ratio"] = c.varianceRatio;
    j["independent_cells"] = cells;
    if (kernel)
      j["suggested_kernel_mm"] = {kernel->lateralMm, kernel->axialMm, kernel->elevationMm};
    else
      j["suggested_kernel_mm"] = nullptr;
    j["autocorrelation_lateral"] = c.lateral;
    j["autocorrelation_axial"] = c.axial;
    emitJson(sp->json, j);
    exitCode = 0;
  });
}

}  // namespace pp5::app
