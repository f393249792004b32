// Constant-interval capture (host/capture.hpp) on the host, for any source:
// a frame is taken once some image corner has moved the interval from the
// last frame taken, in translation and in rotation, and the Acquisition
// thread leaves the others out and counts them. Also the recorder that
// writes a live source's frames, and the viewer's on a thread of its own
// (host/recorder.hpp).
#include <gtest/gtest.h>

#include <glm/gtc/matrix_transform.hpp>

#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>

#include "core/error.hpp"
#include "formats/sequence_io.hpp"
#include "host/acquisition.hpp"
#include "host/capture.hpp"
#include "outputs/outputs.hpp"
#include "host/recorder.hpp"

namespace {

using namespace pp5;

Frame blank(int w, int h, std::uint64_t index) {
  Frame f;
  f.allocate(w, h, PixelType::U8);
  f.index = index;
  return f;
}

// An empty folder of the temporary directory, named for the test and process.
std::filesystem::path freshDir(const std::string& name) {
  const auto dir = std::filesystem::temp_directory_path() / (name + "-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

// A recording that failed: no sequence, and its journal holding `frames` frames.
void expectOnlyTheJournal(const std::string& seq, std::size_t frames) {
  EXPECT_FALSE(std::filesystem::exists(seq)) << seq;
  ASSERT_TRUE(std::filesystem::exists(seq + ".journal")) << seq;
  EXPECT_EQ(readAllFrames(seq + ".journal").size(), frames) << seq;
}

// 0.3 mm pixels; the image slides along z by `stepMm` a frame.
Mat4 slid(double mm) { return glm::translate(Mat4(1.0), Vec3(0.0, 0.0, mm)) * glm::scale(Mat4(1.0), Vec3(0.3, 0.3, 1.0)); }

TEST(IntervalCapture, TakesAFrameEachTimeTheImageHasMovedTheInterval) {
  host::IntervalCapture c(2.0);
  const Frame f = blank(100, 80, 0);
  std::vector<int> taken;
  for (int i = 0; i < 20; ++i)
    if (c.take(f, slid(0.7 * i))) taken.push_back(i);
  // 0, then 0.7 * 3 = 2.1 mm on, then 2.1 mm from there, ...
  EXPECT_EQ(taken, (std::vector<int>{0, 3, 6, 9, 12, 15, 18}));
  EXPECT_EQ(c.taken(), 7u);
  EXPECT_EQ(c.skipped(), 13u);
}

TEST(IntervalCapture, RotationMovesTheFarCorner) {
  // A 100 x 80 image of 0.3 mm pixels turned about its corner (0, 0): the far
  // corner, 38.4 mm away, moves 38.4 * angle; 2 mm takes about 3 degrees.
  host::IntervalCapture c(2.0);
  const Frame f = blank(100, 80, 0);
  const Mat4 px = glm::scale(Mat4(1.0), Vec3(0.3, 0.3, 1.0));
  auto turned = [&](double deg) { return glm::rotate(Mat4(1.0), glm::radians(deg), Vec3(0, 0, 1)) * px; };
  EXPECT_TRUE(c.take(f, turned(0.0)));
  EXPECT_FALSE(c.take(f, turned(2.9)));
  EXPECT_TRUE(c.take(f, turned(3.1)));
  EXPECT_FALSE(c.take(f, turned(3.1)));
}

TEST(IntervalCapture, ZeroTakesEveryFrameAndANegativeIntervalIsRefused) {
  host::IntervalCapture every;
  const Frame f = blank(10, 10, 0);
  for (int i = 0; i < 5; ++i) EXPECT_TRUE(every.take(f, slid(0.0)));
  EXPECT_THROW(host::IntervalCapture(-1.0), InputError);
}

TEST(Acquisition, ConstantIntervalCaptureLeavesFramesOutAndCountsThem) {
  host::Source src;
  src.description = "sliding test source";
  src.frames = 30;
  src.run = [](const host::FrameSink& sink) {
    for (int i = 0; i < 30; ++i) sink(blank(40, 30, static_cast<std::uint64_t>(i)), slid(0.5 * i), 0.01 * i);
  };
  host::Acquisition acq(src, {}, 64, host::DropPolicy::Oldest, 0.0, 2.0);
  std::vector<std::uint64_t> got;
  while (!acq.finished()) {
    host::AcquiredFrame a;
    while (acq.tryPop(a)) got.push_back(a.frame.index);
  }
  host::AcquiredFrame a;
  while (acq.tryPop(a)) got.push_back(a.frame.index);
  EXPECT_EQ(got, (std::vector<std::uint64_t>{0, 4, 8, 12, 16, 20, 24, 28}));
  EXPECT_EQ(acq.skipped(), 22u);
  EXPECT_EQ(acq.dropped(), 0u);
  EXPECT_EQ(acq.given(), 30u);
}

// popFor hands over each frame of an unpaced file source in order, waiting on
// the queue (the one-process run's loop), and then reports the end.
TEST(Acquisition, PopForTakesEveryFrameOfAFileInOrder) {
  host::Source src;
  src.frames = 50;
  src.run = [](const host::FrameSink& sink) {
    for (int i = 0; i < 50; ++i) sink(blank(16, 8, static_cast<std::uint64_t>(i)), slid(1.0 * i), 0.01 * i);
  };
  host::Acquisition acq(src, {}, 2, host::DropPolicy::Oldest, 0.0);
  std::vector<std::uint64_t> got;
  for (;;) {
    host::AcquiredFrame a;
    if (acq.popFor(a, std::chrono::milliseconds(20))) got.push_back(a.frame.index);
    else if (acq.finished()) break;
  }
  ASSERT_EQ(got.size(), 50u);
  for (std::size_t i = 0; i < got.size(); ++i) EXPECT_EQ(got[i], i);
  EXPECT_EQ(acq.dropped(), 0u);
}

// A stop ends a paced source's wait for its next frame at once (it slept to
// the frame's time first: at a slow pace Ctrl-C waited, then took one more
// frame), and a file source blocked on a full queue is released too.
TEST(Acquisition, StopEndsAPacedWaitAndAFullQueuesWait) {
  for (const double pace : {0.2, 0.0}) {
    SCOPED_TRACE(pace);
    host::Source src;
    src.run = [](const host::FrameSink& sink) {
      for (int i = 0; i < 1000; ++i) sink(blank(16, 8, static_cast<std::uint64_t>(i)), slid(1.0 * i), 0.01 * i);
    };
    auto acq = std::make_unique<host::Acquisition>(src, host::Preprocess{}, 1, host::DropPolicy::Oldest, pace);
    host::AcquiredFrame a;
    ASSERT_TRUE(acq->popFor(a, std::chrono::seconds(10)));  // the first frame is due at once
    EXPECT_EQ(a.frame.index, 0u);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));  // the source now waits: for frame 1's time, or for room
    const auto t0 = std::chrono::steady_clock::now();
    acq->stop();
    acq.reset();  // joins the source's thread
    // At 0.2 frames/s frame 1 is due 5 s after frame 0; without the stop's wake-up this would wait for it.
    EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 2.5);
  }
}

}  // namespace

// ---- the recorder (host/recorder.hpp) ----

// A recording whose sequence cannot be finished (here its folder stops taking
// new files, as a full or read-only disk would) fails saying where its frames
// are kept and how to restore them, and the journal holds every frame.
TEST(Recorder, AFailedFinishSaysWhereTheFramesAreKept) {
  namespace fs = std::filesystem;
  const fs::path dir = freshDir("pp5rec");
  const std::string seq = (dir / "rec.mha").string();
  auto rec = std::make_unique<host::Recorder>(seq);
  Frame f;
  f.allocate(8, 6, PixelType::U8);
  for (int i = 0; i < 3; ++i) {
    f.index = static_cast<std::uint64_t>(i);
    f.pixels.assign(f.pixels.size(), static_cast<std::uint8_t>(10 * i));
    rec->write(f);
  }
  // The folder refuses new files: its mode, or for root the immutable attribute.
  fs::permissions(dir, fs::perms::owner_read | fs::perms::owner_exec);
  const bool readOnly = ::access(dir.c_str(), W_OK) != 0 ||
                        std::system(("chattr +i " + dir.string() + " 2>/dev/null").c_str()) == 0;
  std::string message;
  if (readOnly) {
    try {
      rec->close();
    } catch (const InputError& e) {
      message = e.what();
    }
  }
  [[maybe_unused]] const int undo = std::system(("chattr -i " + dir.string() + " 2>/dev/null").c_str());
  fs::permissions(dir, fs::perms::owner_all);
  rec.reset();
  if (!readOnly) {
    fs::remove_all(dir);
    GTEST_SKIP() << "cannot make a read-only folder here";
  }
  EXPECT_NE(message.find("rec.mha.journal"), std::string::npos) << message;
  EXPECT_NE(message.find("pp5echo restore"), std::string::npos) << message;
  EXPECT_NE(message.find("3 frames"), std::string::npos) << message;
  const auto frames = readAllFrames(seq + ".journal");
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_EQ(frames[2].pixels[0], 20);
  EXPECT_FALSE(fs::exists(seq));
  fs::remove_all(dir);
}

// A frame the sequence cannot take (a size that differs from the first's)
// fails the recording; the sequence is abandoned and the journal kept with
// every frame before it, never discarded as if the sequence were complete.
TEST(Recorder, AFailedWriteKeepsTheJournal) {
  namespace fs = std::filesystem;
  const fs::path dir = freshDir("pp5recw");
  const std::string seq = (dir / "rec.mha").string();
  {
    host::Recorder rec(seq);
    Frame f;
    f.allocate(8, 6, PixelType::U8);
    rec.write(f);
    f.allocate(9, 6, PixelType::U8);
    EXPECT_THROW(rec.write(f), InputError);
    rec.close();
  }
  expectOnlyTheJournal(seq, 1);
  fs::remove_all(dir);
}

// The viewer's recordings on their own thread: every frame, in order, with
// its ImageToReference, in the file asked for when it came; a recording
// stopped and another started goes on in a new file; finish() returns with
// the files complete.
TEST(RecorderThread, WritesEveryFrameInOrderInTheFileAskedFor) {
  namespace fs = std::filesystem;
  const fs::path dir = freshDir("pp5rect");
  const std::string a = (dir / "a.mha").string(), b = (dir / "b.mha").string();
  {
    host::RecorderThread rec;
    Frame f;
    f.allocate(64, 48, PixelType::U8);
    for (int i = 0; i < 40; ++i) {
      rec.record(i < 5 ? "" : i < 25 ? a : i < 30 ? "" : b);  // none, a, none, b
      f.index = static_cast<std::uint64_t>(i);
      f.pixels.assign(f.pixels.size(), static_cast<std::uint8_t>(i));
      rec.writePlaced(f, slid(0.5 * i), 0.1 * i);
    }
    rec.finish();
    EXPECT_EQ(rec.path(), "");
    const auto fa = readAllFrames(a), fb = readAllFrames(b);
    ASSERT_EQ(fa.size(), 20u);
    ASSERT_EQ(fb.size(), 10u);
    for (std::size_t k = 0; k < fa.size(); ++k) {
      EXPECT_EQ(static_cast<std::size_t>(fa[k].pixels[0]), 5 + k);
      EXPECT_DOUBLE_EQ(fa[k].timestamp, 0.1 * static_cast<double>(5 + k));
      const FrameTransform* t = fa[k].findTransform("ImageToReference");
      ASSERT_NE(t, nullptr);
      EXPECT_NEAR(t->matrix[3][2], 0.5 * static_cast<double>(5 + k), 1e-9);
    }
    EXPECT_EQ(fb.front().pixels[0], 30);
    EXPECT_EQ(fb.back().pixels[0], 39);
  }
  EXPECT_FALSE(fs::exists(a + ".journal"));  // complete: the journals discarded
  EXPECT_FALSE(fs::exists(b + ".journal"));
  fs::remove_all(dir);
}

// A frame the recording cannot take fails it on the writing thread; the
// caller hears it once, at its next call, the recording is over (later
// frames go nowhere) and the journal keeps the frames before.
TEST(RecorderThread, AFailedWriteReachesTheCallerOnce) {
  namespace fs = std::filesystem;
  const fs::path dir = freshDir("pp5recf");
  const std::string seq = (dir / "rec.mha").string();
  {
    host::RecorderThread rec;
    rec.record(seq);
    Frame good, bad;
    good.allocate(8, 6, PixelType::U8);
    bad.allocate(9, 6, PixelType::U8);  // another size: the sequence refuses it
    rec.writePlaced(good, slid(0.0), 0.0);
    rec.writePlaced(bad, slid(1.0), 0.1);
    bool thrown = false;
    for (int i = 0; i < 6000 && !thrown; ++i) {  // the writer's thread gets to it (30 s at most)
      try {
        rec.record(seq);  // as the viewer calls it, before every frame
        rec.writePlaced(good, slid(2.0), 0.2);
      } catch (const InputError&) {
        thrown = true;
      }
      if (!thrown) std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    EXPECT_TRUE(thrown);
    EXPECT_EQ(rec.path(), "");
    for (int i = 0; i < 3; ++i) {  // said once; the failed recording is not opened again
      EXPECT_NO_THROW(rec.record(seq));
      EXPECT_NO_THROW(rec.writePlaced(good, slid(3.0), 0.3));
    }
    EXPECT_EQ(rec.path(), "");
    EXPECT_NO_THROW(rec.finish());
  }
  expectOnlyTheJournal(seq, 1);
  fs::remove_all(dir);
}

// A recording that fails after the caller has moved on to another: the
// caller hears of it, and the one open loses no frame for it.
TEST(RecorderThread, AnEarlierRecordingsFailureCostsTheNextNothing) {
  namespace fs = std::filesystem;
  const fs::path dir = freshDir("pp5recn");
  const std::string a = (dir / "a.mha").string(), b = (dir / "b.mha").string();
  {
    host::RecorderThread rec;
    Frame good, bad;
    good.allocate(8, 6, PixelType::U8);
    bad.allocate(9, 6, PixelType::U8);
    rec.record(a);
    rec.writePlaced(good, slid(0.0), 0.0);
    rec.writePlaced(bad, slid(1.0), 0.1);  // fails a, once the writer gets to it
    rec.record(b);
    int thrown = 0;
    for (int i = 0; i < 5; ++i) {
      try {
        rec.writePlaced(good, slid(i), 0.1 * i);
      } catch (const InputError&) {
        ++thrown;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    try {
      rec.finish();
    } catch (const InputError&) {
      ++thrown;
    }
    EXPECT_EQ(thrown, 1);
    EXPECT_FALSE(fs::exists(a));
    EXPECT_EQ(readAllFrames(b).size(), 5u);
  }
  fs::remove_all(dir);
}

// A recording that cannot be closed (its folder stopped taking files) is
// said in the log, its frames stay in its journal, and the recording asked
// for next is written all the same.
TEST(RecorderThread, AFailedCloseLeavesTheNextRecordingWhole) {
  namespace fs = std::filesystem;
  const fs::path dir = freshDir("pp5recc");
  fs::create_directories(dir / "a");
  fs::create_directories(dir / "b");
  const std::string a = (dir / "a" / "rec.mha").string(), b = (dir / "b" / "rec.mha").string();
  host::RecorderThread rec;
  rec.record(a);
  Frame f;
  f.allocate(8, 6, PixelType::U8);
  for (int i = 0; i < 3; ++i) rec.writePlaced(f, slid(i), 0.1 * i);
  // Once the writer has journalled them, folder a stops taking files.
  bool journalled = false;
  for (int i = 0; i < 6000 && !journalled; ++i) {  // 30 s at most
    journalled = fs::exists(a + ".journal") && readAllFrames(a + ".journal").size() == 3;
    if (!journalled) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  ASSERT_TRUE(journalled);
  const fs::path da = dir / "a";
  fs::permissions(da, fs::perms::owner_read | fs::perms::owner_exec);
  const bool readOnly = ::access(da.c_str(), W_OK) != 0 ||
                        std::system(("chattr +i " + da.string() + " 2>/dev/null").c_str()) == 0;
  rec.record(b);
  for (int i = 0; i < 2; ++i) rec.writePlaced(f, slid(i), 0.1 * i);
  EXPECT_NO_THROW(rec.finish());
  [[maybe_unused]] const int undo = std::system(("chattr -i " + da.string() + " 2>/dev/null").c_str());
  fs::permissions(da, fs::perms::owner_all);
  if (!readOnly) {
    fs::remove_all(dir);
    GTEST_SKIP() << "cannot make a read-only folder here";
  }
  expectOnlyTheJournal(a, 3);
  EXPECT_EQ(readAllFrames(b).size(), 2u);
  EXPECT_FALSE(fs::exists(b + ".journal"));
  fs::remove_all(dir);
}

// The run folder: an earlier run's outputs go when the run starts, the run's
// own settings file and recordings stay, and a run refused before it started
// leaves the folder as it found it.
TEST(RunFolder, ClearsAnEarlierRunButNotWhatItMustKeep) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("pp5runf-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  auto touch = [&](const char* n) { std::ofstream(dir / n) << "x"; };
  for (const char* n : {"buildup.gif", "final_over.png", "mpr_axial.png", "settings.toml", "stats.csv",
                        "recording.mha", "recording.mha.journal", "notes.txt"})
    touch(n);
  const fs::path marker = dir / host::RunFolder::kIncompleteMarker;
  {
    host::RunFolder refused(dir.string());
    EXPECT_TRUE(fs::exists(marker));
  }
  EXPECT_FALSE(fs::exists(marker)) << "a refused run marked the earlier, complete one unfinished";
  EXPECT_TRUE(fs::exists(dir / "buildup.gif"));
  {
    host::RunFolder f(dir.string());
    f.start({(dir / "settings.toml").string()});
    for (const char* n : {"buildup.gif", "final_over.png", "mpr_axial.png", "stats.csv"})
      EXPECT_FALSE(fs::exists(dir / n)) << n;
    for (const char* n : {"settings.toml", "recording.mha", "recording.mha.journal", "notes.txt"})
      EXPECT_TRUE(fs::exists(dir / n)) << n;
  }
  EXPECT_TRUE(fs::exists(marker)) << "a run that never finished left no mark";
  {
    host::RunFolder refused(dir.string());
  }
  EXPECT_TRUE(fs::exists(marker)) << "a refused run removed an earlier unfinished run's mark";
  {
    host::RunFolder f(dir.string());
    f.start({});
    f.finished();
  }
  EXPECT_FALSE(fs::exists(marker));
  fs::remove_all(dir);
}
