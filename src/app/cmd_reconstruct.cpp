// `pp5echo reconstruct SEQUENCE --plus-config X.xml [--config C.toml] -o volume.mha`
#include <cmath>
#include <cstdio>
#include <memory>

#include <spdlog/spdlog.h>

#include "core/threads.hpp"
#include "app/commands.hpp"
#include "reconstruction/recon_run.hpp"
#include "app/settings.hpp"
#include "analysis/speckle_run.hpp"
#include "core/error.hpp"
#include "core/io_util.hpp"
#include "formats/volume_io.hpp"

namespace pp5::app {


void addReconstructCommand(CLI::App& app, int& exitCode) {
  struct Opts {
    std::string sequence, plusConfig, config, output, weights, writeSettings, type = "uint8";
    std::vector<std::string> overrides;
    int threads = -1;
  };
  auto o = std::make_shared<Opts>();
  auto* cmd = app.add_subcommand("reconstruct", "Reconstruct a tracked PLUS sequence into a volume");
  cmd->add_option("SEQUENCE", o->sequence, "PLUS sequence (.igs.mha, .mhd, .igs.nrrd)")->required();
  cmd->add_option("--plus-config", o->plusConfig,
                  "PLUS device-set XML: the calibration (CoordinateDefinitions) and, unless --config is "
                  "given, the VolumeReconstruction settings")
      ->required();
  cmd->add_option("-c,--config", o->config,
                  "TOML settings ([recon], [grid]); they replace the XML's VolumeReconstruction element");
  cmd->add_option("--set", o->overrides, "Override a TOML option: key=value (repeatable; implies TOML settings)");
  cmd->add_option("-o,--output", o->output, "Output volume (.mha, .mhd, .nrrd)")->required();
  cmd->add_option("--weights", o->weights, "Also write the accumulated weight per voxel (float32)");
  cmd->add_option("--write-settings", o->writeSettings,
                  "Also write the settings used as TOML, a kernel derived from the frames (recon.kernel_from_frames) "
                  "included: `-c` with it reconstructs the same volume (needs TOML settings: -c or --set)");
  cmd->add_option("--type", o->type, "Voxel type of the output volume")->check(CLI::IsMember({"uint8", "float32"}));
  cmd->add_option("--threads", o->threads, "Threads (0 = every core); overrides recon.threads")
      ->check(CLI::Range(0, kMaxThreads));
  cmd->callback([o, &exitCode] {
    PosedSequence seq = openPosedSequence(o->sequence, o->plusConfig);
    gp::ReconSettings rs;
    Vec3 plusSpacing;
    Settings s;
    ConfigSchema schema;
    registerAll(schema, s);
    const bool useToml = !o->config.empty() || !o->overrides.empty();
    if (useToml) {
      loadSettings(schema, o->config, o->overrides);
      rs = s.recon;
      deriveKernelFromFrames(seq, rs, schema);
    } else {
      if (!o->writeSettings.empty())
        throw InputError("--write-settings writes TOML settings, but these come from " + o->plusConfig +
                         "'s VolumeReconstruction element: give them with -c or --set");
      if (!seq.config.volumeReconstruction)
        inputError(o->plusConfig, "has no VolumeReconstruction element; give the settings with --config");
      rs = gp::fromPlus(*seq.config.volumeReconstruction);
      plusSpacing = seq.config.volumeReconstruction->outputSpacing;
    }
    if (o->threads >= 0) rs.threads = o->threads;

    const Grid grid = commandGrid(seq, rs, useToml ? &s.grid : nullptr, plusSpacing);
    const std::string what = useToml && !o->config.empty() ? o->config : o->plusConfig;
    auto recon = gp::makeReconstructor(grid, rs, useToml ? s.grid.memoryLimitBytes() : 0, what);
    spdlog::info("reconstruct: {} frames of {}x{} into {}x{}x{} voxels of {} mm ({} / {}, {} arithmetic)",
                 seq.reader->info().frameCount, seq.reader->info().width, seq.reader->info().height, grid.dims.x,
                 grid.dims.y, grid.dims.z, grid.spacing.x, enumName(rs.method), enumName(rs.pixel.compounding), enumName(rs.arithmetic));

    const gp::ReconRunStats st = runReconstruction(seq, *recon);
    writeVolume(o->output, recon->output().as(o->type == "float32" ? ScalarType::F32 : ScalarType::U8));
    if (!o->writeSettings.empty()) {
      s.recon = rs;  // as used: the derived kernel, the --threads override
      io::AtomicFile f(o->writeSettings);
      f.write("# pp5echo reconstruct " + o->sequence + ": the settings it used\n" + schema.toToml());
      f.commit();
    }
    if (!o->weights.empty()) writeVolume(o->weights, recon->weights());

    std::uint64_t covered = 0;
    for (std::size_t i = 0; i < grid.voxelCount(); ++i) covered += recon->covered(i) ? 1 : 0;
    std::printf("reconstructed %llu of %llu frames in %.2f s (%.1f frames/s); skipped %llu "
                "(%llu INVALID status, %llu non-finite pose), %llu left out by skip_interval\n",
                static_cast<unsigned long long>(st.inserted), static_cast<unsigned long long>(st.frames), st.seconds,
                st.seconds > 0 ? static_cast<double>(st.inserted) / st.seconds : 0.0,
                static_cast<unsigned long long>(st.skipped), static_cast<unsigned long long>(seq.invalidStatus),
                static_cast<unsigned long long>(seq.nonFinite), static_cast<unsigned long long>(st.notSelected));
    std::printf("grid %lldx%lldx%lld, spacing %g %g %g mm, origin %g %g %g mm; %.1f%% of voxels covered\n",
                static_cast<long long>(grid.dims.x), static_cast<long long>(grid.dims.y),
                static_cast<long long>(grid.dims.z), grid.spacing.x, grid.spacing.y, grid.spacing.z, grid.origin.x,
                grid.origin.y, grid.origin.z, 100.0 * static_cast<double>(covered) / static_cast<double>(grid.voxelCount()));
    std::printf("wrote %s%s%s%s%s\n", o->output.c_str(), o->weights.empty() ? "" : " and ", o->weights.c_str(),
                o->writeSettings.empty() ? "" : " and ", o->writeSettings.c_str());
    exitCode = 0;
  });
}

}  // namespace pp5::app
