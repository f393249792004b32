#pragma once
// The source `pp5echo run` streams (run.source), made from the settings: the
// simulator, a PLUS sequence file, the USB interface board or an OpenIGTLink
// server, each a host::Source (host/sources.hpp). With run.record set, every
// frame a source produces is also written to a PLUS sequence file.
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
