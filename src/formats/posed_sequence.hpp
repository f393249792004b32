#pragma once
// A PLUS sequence with every frame's ImageToReference worked out from its
// header and a PLUS device-set config, before any pixel is read: what
// `reconstruct`, `evaluate`, the bench and the sequence source stream.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "formats/plus_config.hpp"
#include "formats/sequence_io.hpp"
#include "core/transform.hpp"

namespace pp5 {

struct PosedSequence {
  std::string path;
  std::unique_ptr<SequenceReader> reader;
  PlusConfig config;
  // Per frame: ImageToReference, or nullopt when the frame cannot be placed
  // (an INVALID image or transform status, or a non-finite pose).
  std::vector<std::optional<Mat4>> poses;
  std::uint64_t invalidStatus = 0;  // frames whose image or transform status is not OK
  std::uint64_t nonFinite = 0;      // frames whose pose has a NaN or infinity
};

// Opens the sequence and computes every frame's pose from the header alone.
// Empty sequences and sequences with no placeable frame are InputErrors.
PosedSequence openPosedSequence(const std::string& sequencePath, const std::string& plusConfigPath);
// The same with a configuration in hand (an empty one places frames that
// carry their ImageToReference, as the host's recordings do).
PosedSequence openPosedSequence(const std::string& sequencePath, PlusConfig config);

}  // namespace pp5
