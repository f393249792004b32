// pp5echo: incremental 3D ultrasound imaging on an emulated Pixel-Planes 5.
#include <cstdio>
#include <exception>

#include <spdlog/spdlog.h>

#include "app/commands.hpp"
#include "core/error.hpp"

int main(int argc, char** argv) {
  CLI::App app{"pp5echo: incremental, interactive 3D ultrasound imaging (Pixel-Planes 5 on MPI)"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "pp5echo 0.1.0");
  bool verbose = false;
  app.add_flag("-v,--verbose", verbose, "Log debugging detail");
  app.parse_complete_callback([&verbose] { spdlog::set_level(verbose ? spdlog::level::debug : spdlog::level::info); });

  int exitCode = 0;
  pp5::app::addConfigCommand(app, exitCode);
  pp5::app::addInfoCommand(app, exitCode);
  pp5::app::addSimulateCommand(app, exitCode);
  pp5::app::addFrameCommand(app, exitCode);
  pp5::app::addReconstructCommand(app, exitCode);
  pp5::app::addEvaluateCommand(app, exitCode);
  pp5::app::addRunCommand(app, exitCode);
  pp5::app::addBenchCommand(app, exitCode);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const pp5::InputError& e) {
    std::fprintf(stderr, "pp5echo: error: %s\n", e.what());
    return 1;
  } catch (const pp5::InvariantError& e) {
    std::fprintf(stderr, "pp5echo: internal error: %s\n", e.what());
    return 3;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pp5echo: error: %s\n", e.what());
    return 1;
  }
  return exitCode;
}
