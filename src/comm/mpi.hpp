#pragma once
// MPI, behind the transport: the only header through which the rest of the
// program reaches MPI, and it does not include <mpi.h>. A process makes one
// MpiSession (MPI_Init ... MPI_Finalize), then one MPI transport over
// MPI_COMM_WORLD for its rank loop.
#include <cstddef>
#include <memory>
#include <string>

#include "comm/transport.hpp"

namespace pp5::comm {

// MPI initialised (one thread calls MPI: MPI_THREAD_FUNNELED) for the
// session's lifetime, finalised when it ends.
class MpiSession {
public:
  MpiSession();
  ~MpiSession();
  MpiSession(const MpiSession&) = delete;
  MpiSession& operator=(const MpiSession&) = delete;

  int rank() const { return rank_; }
  int size() const { return size_; }
  // The transport over every rank of the job (MPI_COMM_WORLD).
  std::unique_ptr<Transport> transport(double timeoutS) const;
  // The fastest one-way time of a message of `bytes` between ranks 0 and 1
  // (the best of `blocks` blocks of `reps` round trips, blocking sends): the
  // link's capacity as far as other work on the machine lets it show. Both
  // ranks call it; the others must not.
  double pingPongSeconds(std::size_t bytes, int reps, int blocks) const;

private:
  int rank_ = 0, size_ = 1;
};

// Prints "pp5echo: rank R (ROLE): message" on stderr and ends the whole job
// (MPI_Abort), so no rank is left waiting for this one.
[[noreturn]] void abortJob(int rank, const char* role, const std::string& message);
// Ends the whole job without a message (a rank whose peer reports the error).
[[noreturn]] void abortJobQuietly();

// True when this process was started by an MPI launcher (mpirun, mpiexec,
// srun), from its environment.
bool launchedByMpi();

}  // namespace pp5::comm
