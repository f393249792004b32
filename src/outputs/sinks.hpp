#pragma once
// The outputs of a run: every sink the job asks for, made in one place
// (sinks.cpp). A sink is one file here and one line in sinks.cpp's list.
#include <memory>
#include <vector>

#include "host/run_loop.hpp"
#include "host/sink.hpp"

namespace pp5::outputs {

using SinkList = std::vector<std::unique_ptr<host::Sink>>;

// The run's outputs: its files in job.outDir (each as the job's options ask)
// and, with job.view.listen, the live viewer (which starts serving here and
// prints its URL; InputError when its address cannot be bound).
SinkList makeSinks(const host::RunJob& job);
// The live viewer alone, or none when job.view.listen is "".
std::unique_ptr<host::Sink> makeViewerSink(const host::RunJob& job);

std::vector<host::Sink*> pointers(const SinkList& sinks);

}  // namespace pp5::outputs
