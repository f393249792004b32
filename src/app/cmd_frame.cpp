// `pp5echo frame SEQUENCE INDEX -o out.png`: one frame of a sequence as an image.
#include <algorithm>
#include <cstdio>
#include <memory>
#include <vector>

#include "app/commands.hpp"
#include "core/error.hpp"
#include "formats/image_io.hpp"
#include "formats/sequence_io.hpp"

namespace pp5::app {

void addFrameCommand(CLI::App& app, int& exitCode) {
  struct Opts {
    std::string sequence, output;
    std::uint64_t index = 0;
  };
  auto opts = std::make_shared<Opts>();
  auto* cmd = app.add_subcommand("frame", "Write one frame of a sequence as an 8-bit PNG (16-bit frames are scaled)");
  cmd->add_option("SEQUENCE", opts->sequence, "PLUS sequence file (.mha, .mhd, .nrrd)")->required();
  cmd->add_option("INDEX", opts->index, "Frame number, from 0")->required();
  cmd->add_option("-o,--output", opts->output, "Output image (.png)")->required();
  cmd->callback([opts, &exitCode] {
    auto reader = SequenceReader::open(opts->sequence);
    const std::uint64_t count = reader->info().frameCount;
    if (opts->index >= count)
      inputError(opts->sequence, "has {} frames; frame {} does not exist", count, opts->index);
    Frame f;
    for (std::uint64_t i = 0; i <= opts->index; ++i)
      if (!reader->next(f)) inputError(opts->sequence, "ended after {} of {} frames", i, count);
    std::vector<std::uint8_t> grey(static_cast<std::size_t>(f.width) * static_cast<std::size_t>(f.height));
    double peak = 1.0;
    if (f.pixelType == PixelType::U16)
      for (int y = 0; y < f.height; ++y)
        for (int x = 0; x < f.width; ++x) peak = std::max(peak, f.value(x, y));
    for (int y = 0; y < f.height; ++y)
      for (int x = 0; x < f.width; ++x) {
        const double v = f.pixelType == PixelType::U8 ? f.value(x, y) : 255.0 * f.value(x, y) / peak;
        grey[static_cast<std::size_t>(y) * static_cast<std::size_t>(f.width) + static_cast<std::size_t>(x)] =
            static_cast<std::uint8_t>(v + 0.5);
      }
    writeGrayPng(opts->output, f.width, f.height, grey.data());
    std::printf("wrote frame %llu (%dx%d) of %s to %s\n", static_cast<unsigned long long>(opts->index), f.width,
                f.height, opts->sequence.c_str(), opts->output.c_str());
    exitCode = 0;
  });
}

}  // namespace pp5::app
