#pragma once
// A recording's journal: while a live scan is written to a PLUS sequence
// (whose header can only be written at the end), every frame is also appended,
// whole and checksummed, to SEQUENCE.journal beside it, with one write(2) per
// frame. A process killed at any moment (SIGKILL, a dead rank, mpirun's
// clean-up) leaves a journal that holds every frame written before the kill:
// a cut or damaged last record is recognised by its length and CRC and left
// out. The journal is removed once the sequence is complete.
//
// A journal is itself readable as a sequence (SequenceReader::open on a
// .journal file), so every command reads a cut-off recording as it is;
// restoreJournal (`pp5echo restore`) turns it into the PLUS sequence it was
// meant to be. The format is in docs/protocol.md.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "core/frame.hpp"
#include "formats/sequence_io.hpp"

namespace pp5 {

// Where the journal of a sequence being written lives: SEQUENCE + ".journal".
std::string journalPathFor(const std::string& sequencePath);

// Checks, before a recording starts, that `sequencePath` can be recorded to:
// a sequence's extension, an existing folder, and no journal left there by a
// recording that was cut off (InputError saying how to restore it).
void checkRecordingTarget(const std::string& sequencePath);

class JournalWriter {
public:
  // Creates the journal of `sequencePath`. One left by an earlier recording
  // that was cut off is never replaced: InputError saying how to restore it.
  JournalWriter(const std::string& sequencePath, const SequenceWriteOptions& opt);
  ~JournalWriter();  // closes the file and keeps it
  JournalWriter(const JournalWriter&) = delete;
  JournalWriter& operator=(const JournalWriter&) = delete;

  // Appends one frame as one record; a failed or short write is an InputError
  // naming the journal. The journal is synced to the disk (fdatasync, checked)
  // when it is created and then with the first frame a second or more after
  // the last sync; a kill of the process loses nothing written, sync or not.
  void append(const Frame& f);
  // The sequence is complete: the journal is closed and removed.
  void discard();
  const std::string& path() const { return path_; }

private:
  void sync();
  std::string path_;
  int fd_ = -1;
  std::uint64_t frames_ = 0;
  double lastSyncS_ = 0.0;
  std::vector<std::uint8_t> record_;  // the record being written
};

// A journal's complete records, read through once (checking every CRC).
struct JournalContents {
  std::string path;
  std::string sequencePath;  // the sequence it belongs to: its own name without .journal
  SequenceWriteOptions options;
  std::uint64_t frames = 0;     // complete records
  std::uint64_t keptBytes = 0;  // up to the end of the last complete record
  std::uint64_t fileBytes = 0;
  std::string cut;  // why reading stopped before the end of the file ("" = it did not)
  bool truncated = false;  // ... because the file ended inside a record (not damage)
  // Damaged records with whole ones after them, each left out alone ("frame N
  // (bytes A to B): why"), and their bytes.
  std::vector<std::string> damaged;
  std::uint64_t damagedBytes = 0;
};

// Opens a journal as a sequence of its complete frames (SequenceReader::open
// does this for a .journal file). InputError when its header is not one.
std::unique_ptr<SequenceReader> openJournal(const std::string& path, JournalContents* contents = nullptr);

// Writes the journal's complete frames to `outPath` (default: the sequence it
// belongs to, which must not exist) as a PLUS sequence with the options the
// recording had, then removes the journal when `outPath` is that sequence and
// no record was damaged (a damaged record costs itself only, and the journal
// is kept), along with the temporary files the cut-off writer left beside it. A journal
// cut off inside its first record is only removed (outPath comes back empty);
// one whose first record is damaged is an InputError and is kept.
// `progress(done, total)` is called as frames are written.
struct RestoreResult {
  JournalContents contents;
  std::string outPath;
  std::uint64_t leftoverTemporaries = 0;  // removed
};
RestoreResult restoreJournal(const std::string& journalPath, std::string outPath = {},
                             const std::function<void(std::uint64_t, std::uint64_t)>& progress = {});

}  // namespace pp5
