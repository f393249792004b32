// libFuzzer target: a PLUS device-set configuration, read as `reconstruct`
// and `calibrate` read it (the coordinate definitions and the chain from Image
// to Reference, the VolumeReconstruction element, the phantom and the
// segmentation). The corpus is the configs of ../shared/data (scripts/fuzz.sh).
#include "analysis/recording.hpp"
#include "formats/plus_config.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pp5;
  const std::string path = fuzz::writeInput(data, size, ".xml");
  fuzz::inputErrorsOnly([&] {
    const PlusConfig cfg = readPlusConfig(path);
    fuzz::inputErrorsOnly([&] { (void)cfg.planImageToReference({"ProbeToTracker", "ReferenceToTracker"}); });
    fuzz::inputErrorsOnly([&] { (void)calib::phantomOf(cfg); });
  });
  return 0;
}
