// libFuzzer target: a MetaIO file (.mha: header and data in one) read as a
// PLUS sequence and as a volume, as `pp5echo info`, `reconstruct` and `view`
// read it. The corpus is made from ../shared/data (scripts/fuzz.sh).
#include <algorithm>

#include "formats/sequence_io.hpp"
#include "formats/volume_io.hpp"
#include "fuzz_util.hpp"

namespace {

void readAll(const std::string& path) {
  using namespace pp5;
  fuzz::inputErrorsOnly([&] {
    auto r = SequenceReader::open(path);
    const auto n = std::min<std::uint64_t>(r->info().frameCount, 32);
    for (std::uint64_t i = 0; i < n; ++i) (void)r->metadata(i);
    Frame f;
    for (int i = 0; i < 32 && r->next(f); ++i) {
    }
  });
  fuzz::inputErrorsOnly([&] { (void)probeImageFile(path); });
  fuzz::inputErrorsOnly([&] { (void)readVolumeHeader(path); });
  fuzz::inputErrorsOnly([&] { (void)readVolume(path); });
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  readAll(pp5::fuzz::writeInput(data, size, FUZZ_EXTENSION));
  return 0;
}
