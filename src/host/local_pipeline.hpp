#pragma once
// The pipeline in one process: the serial pipeline (pipeline/serial_pipeline.hpp)
// behind the run loop's interface, what `pp5echo run --serial` (and any run
// without mpirun) drives. Every call is synchronous.
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "host/pipeline.hpp"
#include "host/run_loop.hpp"
#include "pipeline/serial_pipeline.hpp"
#include "pipeline/work_census.hpp"

namespace pp5::host {

class LocalPipeline final : public Pipeline {
public:
  // Over the job's grid (InputError when it does not fit in memory); with
  // job.census, each frame's work is counted and written once the input ends.
  explicit LocalPipeline(const RunJob& job);
  // A volume read from a file, rendered like a reconstructed one (`pp5echo view`).
  LocalPipeline(const Volume& volume, const RunJob& job);

  std::vector<std::string> statsColumns() const override;
  std::chrono::milliseconds frameWait(bool steered) const override;
  void insert(AcquiredFrame& a) override;
  bool synchronous() const override { return true; }
  std::uint32_t control(std::uint32_t changes, const ViewState& next, bool lasting) override;
  void sync() override;
  ImageView image() const override;
  std::vector<float> composite(pp::CompositeMode mode) override;
  bool requestVolume() override;
  const Volume& volume() override { return pipe_->reconstructor().output(); }
  PipelineCounters counters() const override;
  void streamEnded() override;
  std::string end(const RunEnd& e) override;

private:
  const RunJob& j_;
  std::unique_ptr<serial::SerialPipeline> pipe_;
  std::unique_ptr<serial::WorkCensus> census_;
  std::uint32_t epoch_ = 0;
  PipelineCounters tally_;  // frames, images and busy times (counters() adds the latency)
  bool pending_ = false;  // an image not yet handed to the loop
  FrameLatency latency_;
  std::vector<serial::FrameStats> frameStats_;
  std::vector<serial::ViewStats> orbitStats_;  // the full re-renders of the run's own views

  void logMemory() const;
};

}  // namespace pp5::host
