#include "app/settings.hpp"

#include <filesystem>

#include "core/error.hpp"

namespace pp5::app {

void registerAll(ConfigSchema& schema, Settings& s) {
  sim::registerOptions(schema, s.sim);

  schema.section("grid", "The reconstruction grid, which is also the grid of the simulated truth volume.");
  schema.option("grid.auto_extent", &s.grid.autoExtent, true,
                "Fit the grid around every frame's corners (PLUS's rule), plus `grid.margin_mm`; "
                "otherwise use `grid.origin` and `grid.dims`.");
  schema.option("grid.origin", &s.grid.origin, {0.0, 0.0, 0.0}, -1e6, 1e6,
                "Centre of voxel (0,0,0) in mm, in the Reference frame (when `auto_extent = false`).");
  schema.option("grid.spacing", &s.grid.spacing, {1.0, 1.0, 1.0}, 1e-3, 100.0, "Voxel size in mm along x, y, z.");
  schema.option("grid.dims", &s.grid.dims, {256, 256, 256}, 1, 100000,
                "Voxels along x, y, z (when `auto_extent = false`).");
  schema.option("grid.margin_mm", &s.grid.marginMm, 2.0, 0.0, 1000.0,
                "Margin added on every side of an automatic extent, in mm.");
  schema.option("grid.memory_limit_gib", &s.grid.memoryLimitGiB, 0.0, 0.0, 1e6,
                "Largest grid memory allowed, in GiB; 0 means the memory the machine has available. "
                "A grid over the limit is refused before anything is allocated.");

  gp::registerOptions(schema, s.recon);

  schema.section("output", "Where results are written.");
  schema.option("output.dir", &s.output.dir, "out/doll", "Output folder, unless the command line gives `-o`.");
  schema.option("output.preview_frames", &s.output.previewFrames, 4, 0, 1000,
                "How many input frames `simulate` also writes as PNG, evenly spread over the sweep.");
}

void loadSettings(ConfigSchema& schema, const std::string& file, const std::vector<std::string>& overrides) {
  schema.applyDefaults();
  if (!file.empty()) {
    if (!std::filesystem::exists(file)) throw InputError(file + ": configuration file not found");
    schema.loadFile(file);
  }
  for (const auto& o : overrides) schema.set(o);
}

}  // namespace pp5::app
