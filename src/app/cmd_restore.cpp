// `pp5echo restore JOURNAL [-o OUT]`: a recording that was cut off (the
// process killed, a rank lost, the machine down) left SEQUENCE.journal beside
// the sequence it was writing; this writes that sequence from the journal's
// complete frames, as the recording would have, and removes the journal.
#include <chrono>
#include <filesystem>
#include <memory>
#include <spdlog/spdlog.h>
#include <string>

#include "app/commands.hpp"
#include "formats/recording_journal.hpp"

namespace pp5::app {

void addRestoreCommand(CLI::App& app, int& exitCode) {
  auto journal = std::make_shared<std::string>();
  auto out = std::make_shared<std::string>();
  auto* cmd = app.add_subcommand(
      "restore", "Write the PLUS sequence a cut-off recording was writing from its journal (SEQUENCE.journal), "
                 "keeping every complete frame");
  cmd->add_option("JOURNAL", *journal, "The journal left beside the sequence (e.g. out/recording.mha.journal)")
      ->required();
  cmd->add_option("-o,--output", *out,
                  "Write here instead (.mha, .mhd, .nrrd); the journal is then kept. Default: the sequence the "
                  "journal belongs to");
  cmd->callback([journal, out, &exitCode] {
    using Clock = std::chrono::steady_clock;
    auto last = Clock::now();
    const RestoreResult r = restoreJournal(*journal, *out, [&](std::uint64_t done, std::uint64_t total) {
      if (Clock::now() - last < std::chrono::seconds(2) || done == total) return;
      last = Clock::now();
      spdlog::info("restore: {} of {} frames written", done, total);
    });
    const JournalContents& c = r.contents;
    if (r.outPath.empty()) {
      std::printf("restore: %s held no complete frame (the recording was cut off before its first); "
                  "nothing was recorded, and the journal is removed\n",
                  c.path.c_str());
      exitCode = 0;
      return;
    }
    std::printf("restore: %llu complete frames from %s\n", static_cast<unsigned long long>(c.frames), c.path.c_str());
    if (!c.cut.empty())
      std::printf("  left out the last %llu bytes, cut off or damaged (%s)\n",
                  static_cast<unsigned long long>(c.fileBytes - c.keptBytes), c.cut.c_str());
    if (!c.damaged.empty()) {
      std::printf("  left out %zu damaged record%s (%llu bytes); every whole frame after %s is kept:\n", c.damaged.size(),
                  c.damaged.size() == 1 ? "" : "s", static_cast<unsigned long long>(c.damagedBytes),
                  c.damaged.size() == 1 ? "it" : "them");
      for (const std::string& d : c.damaged) std::printf("    %s\n", d.c_str());
      std::printf("  the journal is kept: remove it yourself once the restored sequence is checked\n");
    }
    if (r.leftoverTemporaries)
      std::printf("  removed %llu temporary file%s the cut-off writer left beside it\n",
                  static_cast<unsigned long long>(r.leftoverTemporaries), r.leftoverTemporaries == 1 ? "" : "s");
    std::printf("wrote %s%s\n", r.outPath.c_str(),
                std::filesystem::exists(c.path) ? " (the journal is kept)" : " (the journal is removed)");
    exitCode = 0;
  });
}

}  // namespace pp5::app
