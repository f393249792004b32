// libFuzzer target: a recording's journal (formats/recording_journal.hpp), the
// file a cut-off recording leaves and `pp5echo info` and `restore` read. A
// journal is damaged by definition (cut at any byte, its last record torn),
// so the reader must keep what is whole and refuse only a header that is not
// a journal's.
//
// With PP5_FUZZ_SEEDS_DIR set, the target writes its seed journals there
// (uint8 and uint16 frames with transforms and custom fields) and exits.
#include <cstdlib>
#include <string>

#include "formats/recording_journal.hpp"
#include "fuzz_util.hpp"

namespace {

void writeSeeds(const std::string& dir) {
  using namespace pp5;
  for (int seed = 0; seed < 3; ++seed) {
    SequenceWriteOptions opt;
    if (seed == 1) opt.fields = {{"UltrasoundImageType", "BRIGHTNESS"}};
    JournalWriter j(dir + "/seed" + std::to_string(seed) + ".mha", opt);
    for (int i = 0; i <= seed; ++i) {
      Frame f;
      f.allocate(4 + seed, 3, seed == 2 ? PixelType::U16 : PixelType::U8);
      for (std::size_t k = 0; k < f.pixels.size(); ++k) f.pixels[k] = static_cast<std::uint8_t>(k * 7 + i);
      f.index = static_cast<std::uint64_t>(i);
      f.timestamp = 0.5 * i;
      f.setTransform("ProbeToTracker", Mat4(1.0), i % 2 == 0);
      f.customFields = {{"FrameNumber", std::to_string(i)}};
      j.append(f);
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  pp5::fuzz::writeSeedsIfAsked(writeSeeds);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pp5;
  const std::string path = fuzz::writeInput(data, size, ".mha.journal");
  fuzz::inputErrorsOnly([&] {
    JournalContents c;
    auto r = openJournal(path, &c);
    for (std::uint64_t i = 0; i < c.frames; ++i) (void)r->metadata(i);
    Frame f;
    while (r->next(f)) {
    }
  });
  return 0;
}
