// libFuzzer target: a TOML settings file, read with every section pp5echo
// registers (`pp5echo config FILE` and every command with -c). The corpus is
// configs/ and the settings.toml files pp5echo writes (scripts/fuzz.sh).
#include "app/settings.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pp5;
  const std::string path = fuzz::writeInput(data, size, ".toml");
  fuzz::inputErrorsOnly([&] { (void)app::readSettings(path, {}); });
  return 0;
}
