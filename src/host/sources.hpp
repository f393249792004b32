#pragma once
// The sources a run can stream, each a host::Source (host/acquisition.hpp)
// that the acquisition thread runs; one file each:
//  - source_simulator.cpp: the simulated sweep (sim/), frame by frame;
//  - source_sequence.cpp: a PLUS sequence file, poses from its device set;
//  - source_board.cpp: the USB interface board (interface_board/), live;
//  - source_igtl.cpp: an OpenIGTLink server (igtl/), live.
// A live source places each frame through a PLUS device set's chain and
// skips (and counts) the frames it cannot place. Every frame a live source
// produces can also be recorded, as it arrives and before any queue can drop
// it, to a PLUS sequence file (recorder.cpp).
#include <memory>
#include <string>

#include "core/grid.hpp"
#include "formats/plus_config.hpp"
#include "formats/posed_sequence.hpp"
#include "host/acquisition.hpp"
#include "igtl/igtl_client.hpp"
#include "interface_board/arm_calibration.hpp"
#include "interface_board/board_driver.hpp"
#include "sim/simulate.hpp"

namespace pp5::host {

// The simulator's sweep, reconstructed into `grid`; `threads` simulate.
Source simulatorSource(std::shared_ptr<sim::SweepSimulator> sim, const Grid& grid, int threads);
// The placeable frames of a sequence, in file order.
Source sequenceSource(std::shared_ptr<PosedSequence> seq, const Grid& grid);

// What every live source needs: the device set whose chain places a frame
// (ImageToReference), the fixed grid (frames not yet acquired cannot be
// fitted), and where to record the frames ("" = nowhere).
struct LiveSetup {
  PlusConfig config;
  Grid grid;
  std::string recordPath;
};
// The interface board: frames from the driver, arm counts turned into
// ProbeToTracker by `arm` (or the pose the board sends, by `transformName`).
Source boardSource(const board::DriverOptions& options, const board::ArmCalibration& arm,
                   const std::string& transformName, const LiveSetup& live);
// An OpenIGTLink server: IMAGE messages paired with their TRANSFORMs.
Source igtlSource(const igtl::ClientOptions& options, const LiveSetup& live);

// The same source, with every frame it produces written to `path` (none when
// `path` is empty).
Source recorded(Source src, const std::string& path);

}  // namespace pp5::host
