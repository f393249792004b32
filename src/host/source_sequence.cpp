#include <fmt/format.h>

#include "host/sources.hpp"

namespace pp5::host {

Source sequenceSource(std::shared_ptr<PosedSequence> seq, const Grid& grid) {
  Source src;
  src.frames = seq->reader->info().frameCount;
  src.description = fmt::format("{} ({} frames of {}x{})", seq->path, src.frames, seq->reader->info().width,
                                seq->reader->info().height);
  src.grid = grid;
  src.run = [seq](const FrameSink& sink) {
    Frame f;
    for (std::uint64_t i = 0; seq->reader->next(f); ++i)
      if (seq->poses[i]) sink(f, *seq->poses[i], f.timestamp);
  };
  return src;
}

}  // namespace pp5::host
