#pragma once
// [igtl] and run.igtl_serve: the OpenIGTLink server a run offers to PlusServer's
// clients (3D Slicer); the server itself is igtl/igtl_server.hpp, its sink
// outputs/igtl_sink.cpp.
#include <string>

namespace pp5 {
class ConfigSchema;
}

namespace pp5::host {

struct IgtlServeSettings {
  std::string serve;       // "[ADDR:]PORT"; "" = no server (`run --igtl-serve` sets it)
  double volumeHz = 10.0;  // the live volume's changes to the clients at most this often
  double viewHz = 30.0;    // the rendered view to the clients at most this often
};
void registerOptions(ConfigSchema& schema, IgtlServeSettings& s);

}  // namespace pp5::host
