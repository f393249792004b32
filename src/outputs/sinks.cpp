#include "outputs/sinks.hpp"

namespace pp5::outputs {

// Each sink's factory, in its own file: nullptr when the job does not want it.
using Factory = std::unique_ptr<host::Sink> (*)(const host::RunJob&);
std::unique_ptr<host::Sink> makeBuildupSink(const host::RunJob& job);
std::unique_ptr<host::Sink> makeFinalImagesSink(const host::RunJob& job);
std::unique_ptr<host::Sink> makeVolumeFilesSink(const host::RunJob& job);
std::unique_ptr<host::Sink> makeOrbitSink(const host::RunJob& job);
std::unique_ptr<host::Sink> makeStatsSink(const host::RunJob& job);
std::unique_ptr<host::Sink> makeSummarySink(const host::RunJob& job);
std::unique_ptr<host::Sink> makeIgtlSink(const host::RunJob& job);

namespace {
// In the order of the closing list of files.
constexpr Factory kSinks[] = {makeBuildupSink, makeFinalImagesSink, makeVolumeFilesSink, makeOrbitSink,
                              makeStatsSink,   makeSummarySink,     makeViewerSink,      makeIgtlSink};
}  // namespace

SinkList makeSinks(const host::RunJob& job) {
  SinkList out;
  for (const Factory f : kSinks)
    if (auto s = f(job)) out.push_back(std::move(s));
  return out;
}

std::vector<host::Sink*> pointers(const SinkList& sinks) {
  std::vector<host::Sink*> out;
  for (const auto& s : sinks) out.push_back(s.get());
  return out;
}

}  // namespace pp5::outputs
