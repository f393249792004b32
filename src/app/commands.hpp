#pragma once
// Each subcommand of `pp5echo` lives in its own cmd_*.cpp and registers itself
// on the CLI11 app. The callback stores the process exit code in `exitCode`.
// Input errors are thrown as pp5::InputError and printed by main() as one line.
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

namespace pp5::app {

void addConfigCommand(CLI::App& app, int& exitCode);
void addInfoCommand(CLI::App& app, int& exitCode);
void addRestoreCommand(CLI::App& app, int& exitCode);
void addSimulateCommand(CLI::App& app, int& exitCode);
void addFrameCommand(CLI::App& app, int& exitCode);
void addReconstructCommand(CLI::App& app, int& exitCode);
void addEvaluateCommand(CLI::App& app, int& exitCode);
void addRunCommand(CLI::App& app, int& exitCode);
void addBenchCommand(CLI::App& app, int& exitCode);
void addCalibrateCommand(CLI::App& app, int& exitCode);
void addSimulateCalibrationCommand(CLI::App& app, int& exitCode);
void addBoardCommands(CLI::App& app, int& exitCode);
// Sends the log to stderr from now on, for a command whose stdout is data
// (`info`'s JSON, `config`'s TOML), so that a pipe gets the data alone.
void logToStderr();
// `pp5echo board-emulator ... -- COMMAND ARGS`: what follows the first `--`.
std::vector<std::string>& trailingCommand();

}  // namespace pp5::app
