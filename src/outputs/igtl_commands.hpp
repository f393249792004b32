#pragma once
// PlusServer's volume reconstruction and recording commands, as the
// OpenIGTLink sink runs them (outputs/igtl_sink.cpp) for PlusServer's clients
// (Slicer's Plus Remote): StartVolumeReconstruction (a region of interest:
// OutputSpacing, OutputOrigin, OutputExtent; OutputVolDeviceName;
// OutputVolFilename), Suspend-, Resume-, StopVolumeReconstruction,
// GetVolumeReconstructionSnapshot (ApplyHoleFilling), ReconstructVolume (a
// sequence in the run's folder, offline, placed by run.plus_config or by its
// frames' own ImageToReference), StartRecording and StopRecording.
//
// As in PlusServer, a commanded reconstruction is a volume of its own: every
// frame that reaches the host from the start on (and not while suspended) is
// inserted into the region asked for, with the run's [recon] settings, on a
// thread of its own so that the run's loop never waits for it; a snapshot and
// the stop send it as an IMAGE named OutputVolDeviceName (after the reply)
// and write it into the run's folder when a file name is given. Commands run
// in the order they came, after the frames that came before them. Recordings
// are journalled as `record`'s are (host/recorder.hpp).
//
// Every attribute is checked before anything is done: numbers finite,
// spacing positive, an extent of at most the memory the run may use, file
// names plain (no folder: they are written in the run's folder) and ending
// in .mha, .mhd or .nrrd. A bad one is a FAIL reply naming it.
#include <memory>

#include "host/run_loop.hpp"
#include "igtl/igtl_server.hpp"

namespace pp5::outputs {

class PlusCommands {
public:
  // Becomes `server`'s command handler.
  PlusCommands(const host::RunJob& job, igtl::Server& server);
  ~PlusCommands();  // finishes what was asked (a recording is closed) and joins
  PlusCommands(const PlusCommands&) = delete;
  PlusCommands& operator=(const PlusCommands&) = delete;

  // Frame k reached the host: queued for a reconstruction or a recording
  // under way (nothing otherwise).
  void frame(const host::AcquiredFrame& a);
  // The input ended: a reconstruction under way is stopped as
  // StopVolumeReconstruction would, a recording closed; waits for both.
  void finish();

  struct Impl;

private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace pp5::outputs
