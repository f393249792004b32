// pp5-igtl-probe: a client of pp5echo's OpenIGTLink server (run.igtl_serve)
// built on Debian's libopenigtlink, for scripts/igtl_rate.sh. It connects
// (retrying while the run starts), reads every message until the server ends
// the connection, and prints one JSON object: per device the messages and
// their rate while it read, and for the live volume the updates (the
// sub-volumes of one snapshot share its timestamp: when the oldest frame
// whose change it carries reached the host, on this machine's wall clock)
// with their rate (one over the median time between two), and each update's latency
// (when its last part arrived minus that timestamp: the latency of its
// oldest frame, the longest of its frames'), median and p95. Other devices'
// rates are over the time from their first message to their last.
//
// Misbehaving on purpose, to show it slows nobody else:
//   --silent-s S   read nothing for the first S seconds after connecting
//   --drop-mid     read half of the first message, then close the connection
//
// Usage: pp5-igtl-probe PORT [--silent-s S] [--drop-mid]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include <igtlClientSocket.h>
#include <igtlMessageHeader.h>

namespace {

double wallNow() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const double at = p * static_cast<double>(v.size() - 1);
  const std::size_t i = static_cast<std::size_t>(at);
  const double f = at - static_cast<double>(i);
  return i + 1 < v.size() ? v[i] * (1 - f) + v[i + 1] * f : v[i];
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: pp5-igtl-probe PORT [--silent-s S] [--drop-mid]\n");
    return 2;
  }
  const int port = std::atoi(argv[1]);
  double silentS = 0.0;
  bool dropMid = false;
  for (int i = 2; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--silent-s" && i + 1 < argc) silentS = std::atof(argv[++i]);
    else if (a == "--drop-mid") dropMid = true;
    else {
      std::fprintf(stderr, "pp5-igtl-probe: unknown argument '%s'\n", a.c_str());
      return 2;
    }
  }
  auto socket = igtl::ClientSocket::New();
  bool connected = false;
  for (int i = 0; i < 1200 && !connected; ++i) {  // up to a minute for the run to start serving
    connected = socket->ConnectToServer("127.0.0.1", port) == 0;
    if (!connected) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  if (!connected) {
    std::fprintf(stderr, "pp5-igtl-probe: no server on 127.0.0.1:%d\n", port);
    return 1;
  }
  socket->SetReceiveTimeout(60000);
  if (silentS > 0) std::this_thread::sleep_for(std::chrono::duration<double>(silentS));
  const double start = wallNow();

  struct PerDevice {
    long messages = 0;
    double bytes = 0;
    double first = 0, last = 0;  // when its first and last message came
  };
  std::map<std::string, PerDevice> devices;
  std::map<double, double> updateArrival;  // the volume's timestamp -> when its last part came
  std::vector<char> body;
  double last = start;
  while (true) {
    auto h = igtl::MessageHeader::New();
    h->InitPack();
    if (socket->Receive(h->GetPackPointer(), h->GetPackSize()) != h->GetPackSize()) break;
    h->Unpack();
    const std::size_t n = static_cast<std::size_t>(h->GetBodySizeToRead());
    body.resize(n);
    if (dropMid) {  // half of the body, then gone
      if (n > 1) socket->Receive(body.data(), static_cast<int>(n / 2));
      socket->CloseSocket();
      std::printf("{\"dropped_mid_message\": true, \"body_bytes\": %zu}\n", n);
      return 0;
    }
    if (n > 0 && socket->Receive(body.data(), static_cast<int>(n)) != static_cast<int>(n)) break;
    last = wallNow();
    const std::string device = h->GetDeviceName();
    PerDevice& d = devices[std::string(h->GetDeviceType()) + ":" + device];
    if (d.messages++ == 0) d.first = last;
    d.last = last;
    d.bytes += static_cast<double>(n);
    if (device == "Volume_Reference") {
      igtlUint32 sec = 0, frac = 0;
      h->GetTimeStamp(&sec, &frac);
      const double stamp = sec + frac / 4294967296.0;
      updateArrival[stamp] = last;
    }
  }
  const double seconds = std::max(1e-9, last - start);
  std::vector<double> latencyMs, arrivals;
  for (const auto& [stamp, arrived] : updateArrival) {
    latencyMs.push_back((arrived - stamp) * 1e3);
    arrivals.push_back(arrived);
  }
  // The rate while the volume changes: one over the median time between
  // updates (a run prepares for seconds before its first frame, and sends
  // its final volume after the final passes).
  std::sort(arrivals.begin(), arrivals.end());
  std::vector<double> gaps;
  for (std::size_t i = 1; i < arrivals.size(); ++i) gaps.push_back(arrivals[i] - arrivals[i - 1]);
  const double gap = percentile(gaps, 0.5);
  const double perS = gap > 0 ? 1.0 / gap : 0.0;
  std::printf("{\"seconds\": %.3f, \"volume_updates\": %zu, \"volume_updates_per_s\": %.2f, "
              "\"volume_latency_ms_median\": %.1f, \"volume_latency_ms_p95\": %.1f, \"volume_latency_ms_max\": %.1f, "
              "\"devices\": {",
              seconds, updateArrival.size(), perS,
              percentile(latencyMs, 0.5), percentile(latencyMs, 0.95), percentile(latencyMs, 1.0));
  bool first = true;
  for (const auto& [name, d] : devices) {
    // The rate while it came: messages over the time from its first to its last.
    const double span = d.last - d.first;
    std::printf("%s\"%s\": {\"messages\": %ld, \"per_s\": %.2f, \"MB\": %.2f}", first ? "" : ", ", name.c_str(),
                d.messages, span > 0 ? static_cast<double>(d.messages - 1) / span : 0.0, d.bytes / 1e6);
    first = false;
  }
  std::printf("}}\n");
  return 0;
}
