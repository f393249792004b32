#pragma once
// An in-process transport: the ranks of one job as threads of one process,
// so that the rank loops run in a test without mpirun (and under the
// sanitizers). Messages keep each sender's order, as MPI's do; the barrier
// and the broadcast are those of the job's threads, and give up after the
// timeout, or at once when the job is aborted (a rank failed). Counting is the base
// Transport's, so the counters read as under MPI.
#include <memory>
#include <vector>

#include "comm/transport.hpp"

namespace pp5::comm {

class LocalJob {
public:
  // `size` ranks; a wait() gives up after `timeoutS`.
  LocalJob(int size, double timeoutS);
  ~LocalJob();
  LocalJob(const LocalJob&) = delete;
  LocalJob& operator=(const LocalJob&) = delete;

  int size() const { return static_cast<int>(ranks_.size()); }
  // Rank r's transport, for the one thread that plays rank r.
  Transport& rank(int r);
  // A rank failed: every barrier and broadcast, now and later, throws
  // CommError instead of waiting for it (MPI_Abort's part for threads).
  void abort();

  struct Hub;

private:
  std::shared_ptr<Hub> hub_;
  std::vector<std::unique_ptr<Transport>> ranks_;
};

}  // namespace pp5::comm
