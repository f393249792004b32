// libFuzzer target: a byte stream from a client of the OpenIGTLink server,
// read as the server reads it (igtl/igtl_protocol.hpp): cut into messages in
// pieces of the sizes the first bytes choose (as recv() may cut them), each
// command parsed and its reply packed. Bad input may only end in InputError
// (the server's one log line and a dropped connection).
//
// With PP5_FUZZ_SEEDS_DIR set, the target writes its seed streams there
// (queries and PlusServer commands packed by the OpenIGTLink library) and exits.
#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include <igtlMessageBase.h>
#include <igtlStatusMessage.h>
#include <igtlStringMessage.h>

#include "core/error.hpp"
#include "igtl/igtl_protocol.hpp"
#include "fuzz_util.hpp"

namespace {

std::string packed(igtl::MessageBase* m) {
  m->Pack();
  return {static_cast<const char*>(m->GetPackPointer()), static_cast<std::size_t>(m->GetPackSize())};
}

std::string command(const char* uid, const char* xml) {
  auto s = igtl::StringMessage::New();
  s->SetDeviceName((std::string("CMD_") + uid).c_str());
  s->SetString(xml);
  return packed(s);
}

void writeSeeds(const std::string& dir) {
  auto put = [&](const std::string& name, const std::string& bytes) {
    std::ofstream(dir + "/seed-" + name, std::ios::binary) << '\x10' << bytes;  // first byte: the piece size
  };
  auto status = igtl::GetStatusMessage::New();
  put("status", packed(status));
  put("start", command("1", R"(<Command Name="StartVolumeReconstruction" OutputSpacing="0.5 0.5 0.5" )"
                            R"(OutputOrigin="0 0 0" OutputExtent="0 9 0 9 0 9" OutputVolDeviceName="RecVol_Reference"/>)"));
  put("snapshot", command("22", R"(<Command Name="GetVolumeReconstructionSnapshot" ApplyHoleFilling="TRUE"/>)") +
                      command("23", R"(<Command Name="StopRecording"/>)"));
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  pp5::fuzz::writeSeedsIfAsked(writeSeeds);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const std::size_t piece = 1 + data[0];
  pp5::igtl::MessageReader reader(64 * 1024);
  pp5::fuzz::inputErrorsOnly([&] {
    for (std::size_t at = 1; at < size; at += piece)
      for (const pp5::igtl::Incoming& m : reader.feed(data + at, std::min(piece, size - at))) {
        if (m.type.empty() || m.device.size() > pp5::igtl::kDeviceNameLength) std::abort();  // the reader checked these
        if (!pp5::igtl::isCommand(m)) continue;
        pp5::fuzz::inputErrorsOnly([&] {
          const pp5::igtl::Command c = pp5::igtl::parseCommand(m);
          if (c.name.empty()) std::abort();
          (void)pp5::igtl::packCommandReply(c, false, c.name + ": " + c.attribute("OutputExtent"));
        });
      }
  });
  return 0;
}
