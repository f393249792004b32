// pp5echo: incremental 3D ultrasound imaging on an emulated Pixel-Planes 5.
#include <algorithm>
#include <memory>
#include <cstdio>
#include <string>
#include <vector>
#include <exception>

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "app/commands.hpp"
#include "core/error.hpp"

void pp5::app::logToStderr() {
  auto log = std::make_shared<spdlog::logger>("pp5echo", std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  log->set_level(spdlog::default_logger()->level());
  spdlog::set_default_logger(std::move(log));
}

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
  pp5::app::addRestoreCommand(app, exitCode);
  pp5::app::addSimulateCommand(app, exitCode);
  pp5::app::addFrameCommand(app, exitCode);
  pp5::app::addReconstructCommand(app, exitCode);
  pp5::app::addEvaluateCommand(app, exitCode);
  pp5::app::addRunCommand(app, exitCode);
  pp5::app::addBenchCommand(app, exitCode);
  pp5::app::addCalibrateCommand(app, exitCode);
  pp5::app::addSimulateCalibrationCommand(app, exitCode);
  pp5::app::addBoardCommands(app, exitCode);

  // board-emulator runs a command given after `--`; keep it away from CLI11.
  std::vector<std::string> args(argv + 1, argv + argc);
  if (std::find(args.begin(), args.end(), "board-emulator") != args.end()) {
    const auto dash = std::find(args.begin(), args.end(), "--");
    if (dash != args.end()) {
      pp5::app::trailingCommand().assign(dash + 1, args.end());
      args.erase(dash, args.end());
    }
  }
  std::reverse(args.begin(), args.end());  // CLI11 takes a reversed vector

  try {
    app.parse(args);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const pp5::InputError& e) {
    std::fprintf(stderr, "pp5echo: error: %s\n", e.what());
    return 1;
  } catch (const pp5::DeviceError& e) {
    std::fprintf(stderr, "pp5echo: device error: %s\n", e.what());
    return 2;
  } catch (const pp5::InvariantError& e) {
    std::fprintf(stderr, "pp5echo: internal error: %s\n", e.what());
    return 3;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pp5echo: error: %s\n", e.what());
    return 1;
  }
  return exitCode;
}
