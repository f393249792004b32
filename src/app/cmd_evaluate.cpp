// `pp5echo evaluate truth|leave-out ...`: reconstruction accuracy.
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "app/commands.hpp"
#include "app/recon_run.hpp"
#include "app/settings.hpp"
#include "core/error.hpp"
#include "core/volume_io.hpp"
#include "gp/evaluation.hpp"

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
  cmd->add_option("--threads", o.threads, "Threads (0 = every core)")->check(CLI::Range(0, 1024));
  cmd->add_option("--json", o.json, "Also write the results as JSON to this file ('-' = standard output)");
}

// Reconstruction settings: TOML when given, else the PLUS config's element.
gp::ReconSettings reconSettings(const CommonOpts& o, const PosedSequence& seq, Settings& s, Vec3* spacing,
                                double* margin) {
  gp::ReconSettings rs;
  if (!o.config.empty() || !o.overrides.empty()) {
    ConfigSchema schema;
    registerAll(schema, s);
    loadSettings(schema, o.config, o.overrides);
    rs = s.recon;
    *spacing = s.grid.spacing;
    *margin = s.grid.marginMm;
  } else {
    if (!seq.config.volumeReconstruction)
      inputError(o.plusConfig, "has no VolumeReconstruction element; give the settings with --config");
    rs = gp::fromPlus(*seq.config.volumeReconstruction);
    *spacing = seq.config.volumeReconstruction->outputSpacing;
    *margin = 0.0;
  }
  if (o.threads >= 0) rs.threads = o.threads;
  return rs;
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
  std::string d(enumName(rs.method));
  if (rs.method != gp::Method::Tent) d += "/" + std::string(enumName(rs.compounding));
  if (rs.method == gp::Method::Tent && rs.fillIn) d += "+fill-in";
  if (rs.fillHoles) d += "+holes";
  return d + " (" + std::string(enumName(rs.arithmetic)) + ")";
}

}  // namespace

void addEvaluateCommand(CLI::App& app, int& exitCode) {
  auto* eval = app.add_subcommand("evaluate", "Measure reconstruction accuracy (ground truth or leave-out)");
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
    Vec3 spacing;
    double margin = 0;
    const gp::ReconSettings rs = reconSettings(*t, seq, s, &spacing, &margin);
    const Volume truthVol = readVolume(t->truth);
    std::uint64_t notFinite = 0;
    for (std::size_t i = 0; i < truthVol.grid.voxelCount(); ++i) notFinite += std::isfinite(truthVol.value(i)) ? 0 : 1;
    if (notFinite > 0)
      inputError(t->truth, "holds {} voxels that are not finite numbers (NaN or infinity): no error can be measured "
                 "against it", notFinite);
    auto recon = gp::makeReconstructor(truthVol.grid, rs, 0, t->truth);
    const ReconRunStats st = runReconstruction(seq, *recon);
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
  leave->callback([l, &exitCode] {
    const gp::LeaveOutReading reading =
        l->reading == "plus" ? gp::LeaveOutReading::PlusGreyLevels : gp::LeaveOutReading::Trilinear;
    PosedSequence seq = openPosedSequence(l->sequence, l->plusConfig);
    Settings s;
    Vec3 spacing;
    double margin = 0;
    gp::ReconSettings rs = reconSettings(*l, seq, s, &spacing, &margin);
    // The leave-out stride replaces SkipInterval: every frame not kept is held out.
    rs.skipInterval = 1;
    const auto k = static_cast<std::uint64_t>(l->keepEvery);
    const Grid grid = chooseGrid(seq, rs, spacing, margin, true);
    auto recon = gp::makeReconstructor(grid, rs, 0, l->plusConfig);
    const ReconRunStats st = runReconstruction(seq, *recon, [k](std::uint64_t i) { return i % k == 0; });

    // Second pass over the file for the held-out frames.
    auto reader = SequenceReader::open(l->sequence);
    const auto cov = [&](std::size_t i) { return recon->hasValue(i); };
    gp::LeaveOutMetrics m;
    Frame f;
    std::vector<gp::PixelRun> runs;  // the clip rectangle and fan, per frame size
    int runsW = -1, runsH = -1;
    for (std::uint64_t i = 0; reader->next(f); ++i) {
      if (i % k == 0 || !seq.poses[i]) continue;
      if (f.width != runsW || f.height != runsH) {
        runs = gp::pixelRuns(f.width, f.height, rs);
        runsW = f.width;
        runsH = f.height;
      }
      gp::compareHeldOutFrame(recon->output(), cov, f, *seq.poses[i], runs, m, reading);
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
    std::printf("  frames            %llu kept, %llu held out, %llu skipped\n",
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
    j["reading"] = l->reading;
    j["keep_every"] = k;
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
}

}  // namespace pp5::app
