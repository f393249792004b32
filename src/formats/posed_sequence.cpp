#include "formats/posed_sequence.hpp"

#include <utility>

#include "core/error.hpp"

namespace pp5 {

PosedSequence openPosedSequence(const std::string& sequencePath, const std::string& plusConfigPath) {
  return openPosedSequence(sequencePath, readPlusConfig(plusConfigPath));
}

PosedSequence openPosedSequence(const std::string& sequencePath, PlusConfig config) {
  PosedSequence seq;
  seq.path = sequencePath;
  seq.reader = SequenceReader::open(sequencePath);
  seq.config = std::move(config);
  const SequenceInfo& info = seq.reader->info();
  if (info.frameCount == 0) inputError(sequencePath, "the sequence has no frames; there is nothing to reconstruct");

  // Fail early, naming the config, when the chain cannot exist at all.
  const Frame first = seq.reader->metadata(0);
  std::vector<std::string> names;
  for (const auto& t : first.transforms) names.push_back(t.name);
  (void)seq.config.planImageToReference(names);

  seq.poses.resize(info.frameCount);
  for (std::uint64_t i = 0; i < info.frameCount; ++i) {
    const Frame m = seq.reader->metadata(i);
    if (!m.imageValid) {
      ++seq.invalidStatus;
      continue;
    }
    const auto pose = imageToReference(seq.config, m);
    if (!pose) {
      ++seq.invalidStatus;
      continue;
    }
    if (!isFinite(*pose)) {
      ++seq.nonFinite;
      continue;
    }
    seq.poses[i] = *pose;
  }
  if (seq.invalidStatus + seq.nonFinite == info.frameCount)
    inputError(sequencePath, "none of its {} frames can be placed ({} with an INVALID status, {} with a non-finite pose)",
               info.frameCount, seq.invalidStatus, seq.nonFinite);
  return seq;
}

}  // namespace pp5
