#pragma once
// The sources `pp5echo run` streams: the simulator, a PLUS sequence file, the
// USB interface board and an OpenIGTLink server (run.source). Each becomes a
// host::Source that the host's acquisition thread runs. With run.record set,
// every frame a source produces is also written, as it arrives and before
// any queue can drop it, to a PLUS sequence file.
#include "app/settings.hpp"
#include "host/acquisition.hpp"
#include "interface_board/arm_calibration.hpp"
#include "interface_board/board_driver.hpp"

namespace pp5::app {

host::Source makeSource(const Settings& s);

// The [board] settings as the driver's options and the arm's calibration.
board::DriverOptions driverOptions(const Settings& s);
board::ArmCalibration armCalibration(const Settings& s);

// `--source board | igtl://HOST:PORT | sequence | simulator` as overrides of
// run.source (and run.igtl_url).
std::vector<std::string> sourceOverrides(const std::string& source);

}  // namespace pp5::app
