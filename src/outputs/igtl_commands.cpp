#include "outputs/igtl_commands.hpp"

#include <charconv>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <mutex>
#include <optional>
#include <sstream>
#include <thread>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "core/error.hpp"
#include "formats/volume_io.hpp"
#include "host/recorder.hpp"
#include "formats/posed_sequence.hpp"
#include "reconstruction/hole_fill.hpp"
#include "reconstruction/recon_run.hpp"
#include "reconstruction/reconstruction.hpp"

namespace pp5::outputs {

namespace fs = std::filesystem;

namespace {

constexpr const char* kDefaultVolumeDevice = "RecVol_Reference";  // Slicer's Plus Remote asks for this name
constexpr std::size_t kMaxQueuedBytes = std::size_t{256} << 20;  // frames waiting for the reconstruction

// `n` numbers separated by spaces; InputError naming the attribute otherwise.
std::vector<double> numbers(const igtl::Command& c, const std::string& key, std::size_t n) {
  const std::string text = c.attribute(key);
  std::istringstream in(text);
  std::vector<double> v;
  std::string word;
  while (in >> word) {
    double x = 0.0;
    const auto [end, ec] = std::from_chars(word.data(), word.data() + word.size(), x);
    if (ec != std::errc() || end != word.data() + word.size() || !std::isfinite(x))
      throw InputError(fmt::format("{}=\"{}\": '{}' is not a finite number", key, text, word));
    v.push_back(x);
  }
  if (v.size() != n) throw InputError(fmt::format("{}=\"{}\": {} numbers needed, {} given", key, text, n, v.size()));
  return v;
}

// A file name for the run's folder: plain (no folder), a volume's or a sequence's extension.
std::string fileIn(const std::string& dir, const igtl::Command& c, const std::string& key) {
  const std::string name = c.attribute(key);
  if (name.empty()) return {};
  const fs::path p(name);
  const std::string ext = p.extension().string();
  if (p.has_parent_path() || name == "." || name == ".." || name.find('\\') != std::string::npos)
    throw InputError(fmt::format("{}=\"{}\": a plain file name, written in the run's folder, is needed", key, name));
  if (ext != ".mha" && ext != ".mhd" && ext != ".nrrd")
    throw InputError(fmt::format("{}=\"{}\": the name must end in .mha, .mhd or .nrrd", key, name));
  return (fs::path(dir) / p).string();
}

std::string deviceName(const igtl::Command& c, const std::string& key, const std::string& otherwise) {
  const std::string d = c.attribute(key, otherwise);
  if (d.empty() || d.size() > igtl::kDeviceNameLength)
    throw InputError(fmt::format("{}=\"{}\": a device name of 1 to {} characters is needed", key, d,
                                 igtl::kDeviceNameLength));
  return d;
}

bool yes(const std::string& v) { return v == "TRUE" || v == "true" || v == "True" || v == "1"; }

Mat4 voxelToReference(const Grid& g) {
  Mat4 m(1.0);
  for (int a = 0; a < 3; ++a) m[a][a] = g.spacing[a];
  m[3] = Vec4(g.origin, 1.0);
  return m;
}

}  // namespace

struct PlusCommands::Impl {
  igtl::Server& server;
  std::string outDir;
  Grid runGrid;
  gp::ReconSettings recon;
  std::uint64_t memoryLimit = 0;

  struct Job {
    bool isFrame = false;
    host::AcquiredFrame frame;
    igtl::Command command;
    igtl::CommandReply reply;
  };
  std::mutex m;
  std::condition_variable cv, idle;
  std::deque<Job> jobs;
  std::size_t queuedBytes = 0;
  bool quit = false, busy = false, finishing = false;
  std::atomic<bool> reconstructing{false}, recordingOn{false};

  // The worker's own.
  std::unique_ptr<gp::Reconstructor> volume;
  bool suspended = false;
  std::string volumeDevice, volumeFile;
  std::uint64_t inserted = 0, skipped = 0, refused = 0;
  host::RecorderThread recorder;
  std::string recording;
  int recordings = 0;
  std::thread thread;

  std::string plusConfig;

  Impl(const host::RunJob& j, igtl::Server& s)
      : server(s), outDir(j.outDir), runGrid(j.grid), recon(j.pipeline.recon), memoryLimit(j.memoryLimitBytes),
        plusConfig(j.plusConfig) {
    recon.threads = 1;  // the host's other work (the loop, the encoders) keeps the other cores
  }

  void push(Job&& job) {
    {
      const std::lock_guard lock(m);
      if (finishing) {
        if (!job.isFrame) job.reply(false, fmt::format("{}: the run's input has ended", job.command.name));
        return;
      }
      if (job.isFrame) {
        const std::size_t bytes = job.frame.frame.pixels.size();
        if (queuedBytes + bytes > kMaxQueuedBytes) {
          ++skipped;  // the reconstruction is that far behind: as PLUS, it skips
          return;
        }
        queuedBytes += bytes;
      }
      jobs.push_back(std::move(job));
    }
    cv.notify_one();
  }

  void run() {
    while (true) {
      Job job;
      {
        std::unique_lock lock(m);
        busy = false;
        idle.notify_all();
        cv.wait(lock, [&] { return quit || !jobs.empty(); });
        if (jobs.empty()) return;
        job = std::move(jobs.front());
        jobs.pop_front();
        if (job.isFrame) queuedBytes -= job.frame.frame.pixels.size();
        busy = true;
      }
      if (job.isFrame) {
        insert(job.frame);
        continue;
      }
      try {
        if (const auto said = execute(job.command, job.reply)) job.reply(true, *said);
      } catch (const InputError& e) {
        job.reply(false, fmt::format("{}: {}", job.command.name, e.what()));
      } catch (const std::exception& e) {
        spdlog::error("igtl: {} failed: {}", job.command.name, e.what());
        job.reply(false, fmt::format("{}: {}", job.command.name, e.what()));
      }
    }
  }

  void insert(const host::AcquiredFrame& a) {
    if (volume && !suspended) {
      try {
        volume->insert(a.frame, a.imageToReference, a.timeS);
        ++inserted;
      } catch (const InputError& e) {
        if (refused++ == 0) spdlog::warn("igtl: the commanded reconstruction refused a frame ({}); such frames are left out", e.what());
      }
    }
    if (!recording.empty()) recorder.writePlaced(a.frame, a.imageToReference, a.timeS);
  }

  Grid regionOfInterest(const igtl::Command& c) const {
    Grid g = runGrid;
    if (c.has("OutputSpacing")) {
      const auto s = numbers(c, "OutputSpacing", 3);
      for (int a = 0; a < 3; ++a)
        if (!(s[static_cast<std::size_t>(a)] > 0.0))
          throw InputError(fmt::format("OutputSpacing=\"{}\": each spacing must be positive", c.attribute("OutputSpacing")));
      g.spacing = Vec3(s[0], s[1], s[2]);
    }
    if (c.has("OutputExtent")) {
      const auto e = numbers(c, "OutputExtent", 6);
      const auto o = c.has("OutputOrigin") ? numbers(c, "OutputOrigin", 3) : std::vector<double>{g.origin.x, g.origin.y, g.origin.z};
      for (int a = 0; a < 3; ++a) {
        const double lo = e[static_cast<std::size_t>(2 * a)], hi = e[static_cast<std::size_t>(2 * a + 1)];
        if (lo != std::floor(lo) || hi != std::floor(hi) || lo > hi || std::abs(lo) > 1e6 || std::abs(hi) > 1e6)
          throw InputError(fmt::format("OutputExtent=\"{}\": whole voxel indices, min <= max, per axis, are needed",
                                       c.attribute("OutputExtent")));
        g.dims[a] = static_cast<std::int64_t>(hi - lo) + 1;
        g.origin[a] = o[static_cast<std::size_t>(a)] + lo * g.spacing[a];
      }
    } else if (c.has("OutputOrigin")) {
      throw InputError("OutputOrigin needs OutputExtent (the region's size in voxels)");
    } else {  // the run's grid, at the spacing asked for
      for (int a = 0; a < 3; ++a)
        g.dims[a] = static_cast<std::int64_t>(std::llround(static_cast<double>(runGrid.dims[a] - 1) * runGrid.spacing[a] / g.spacing[a])) + 1;
    }
    return g;
  }

  // The commanded volume as uint8, hole-filled when asked (PLUS's methods).
  Volume output(bool holeFilling) const {
    if (holeFilling && recon.method != gp::Method::Tent) {
      const auto& el = recon.pixel.holeFilling.empty() ? gp::HoleFiller::defaultElements() : recon.pixel.holeFilling;
      return gp::fillHoles(volume->output(), volume->weights(), el, recon.arithmetic == gp::Arithmetic::Plus).as(ScalarType::U8);
    }
    return volume->output().as(ScalarType::U8);
  }

  // Writes the commanded volume, replies, then sends it.
  void deliver(const igtl::Command& c, const igtl::CommandReply& reply, bool holeFilling, const std::string& verb) {
    const std::string device = deviceName(c, "OutputVolDeviceName", volumeDevice);
    const std::string file = c.has("OutputVolFilename") ? fileIn(outDir, c, "OutputVolFilename") : volumeFile;
    volume->finish();
    const Volume v = output(holeFilling);
    if (!file.empty()) writeVolume(file, v, true);
    const std::string said = fmt::format("{} {} ({}x{}x{} voxels, {} frames{}){}", verb, device, v.grid.dims.x,
                                         v.grid.dims.y, v.grid.dims.z, inserted,
                                         skipped ? fmt::format(", {} skipped as it lagged", skipped) : "",
                                         file.empty() ? "" : fmt::format(", written to {}", file));
    reply(true, said);  // the reply first, then the volume, as PlusServer sends them
    server.publishImage(device, v.grid.dims, v.bytes.data(), voxelToReference(v.grid), 0.0);
  }

  // Runs one command: its reply's message, or InputError (a FAIL naming why).
  // The commands that send a volume reply themselves, as the reply must come
  // before the volume, and return nullopt.
  std::optional<std::string> execute(const igtl::Command& c, const igtl::CommandReply& reply) {
    const std::string& n = c.name;
    if (n == "StartVolumeReconstruction") {
      if (volume) throw InputError("a reconstruction is under way; stop it first");
      const Grid g = regionOfInterest(c);
      const std::string device = deviceName(c, "OutputVolDeviceName", kDefaultVolumeDevice);
      const std::string file = fileIn(outDir, c, "OutputVolFilename");
      volume = gp::makeReconstructor(g, recon, memoryLimit, "StartVolumeReconstruction's region");
      volumeDevice = device;
      volumeFile = file;
      suspended = false;
      inserted = skipped = refused = 0;
      reconstructing = true;
      return fmt::format("reconstructing into {}x{}x{} voxels of {} x {} x {} mm from ({}, {}, {}) mm as {}", g.dims.x,
                         g.dims.y, g.dims.z, g.spacing.x, g.spacing.y, g.spacing.z, g.origin.x, g.origin.y, g.origin.z,
                         device);
    }
    if (n == "SuspendVolumeReconstruction" || n == "ResumeVolumeReconstruction") {
      if (!volume) throw InputError("no reconstruction is under way");
      suspended = n == "SuspendVolumeReconstruction";
      reconstructing = !suspended;
      return suspended ? "suspended" : "resumed";
    }
    if (n == "GetVolumeReconstructionSnapshot") {
      if (!volume) throw InputError("no reconstruction is under way");
      deliver(c, reply, yes(c.attribute("ApplyHoleFilling")), "snapshot of");
      return std::nullopt;
    }
    if (n == "StopVolumeReconstruction") {
      if (!volume) throw InputError("no reconstruction is under way");
      reconstructing = false;
      deliver(c, reply, true, "stopped");
      volume.reset();
      return std::nullopt;
    }
    if (n == "ReconstructVolume") {
      // A sequence in the run's folder (a recording made with StartRecording, or one put there), offline.
      const std::string in = fileIn(outDir, c, "InputSeqFilename");
      if (in.empty()) throw InputError("InputSeqFilename: the sequence to reconstruct is needed");
      if (!fs::exists(in)) throw InputError(fmt::format("InputSeqFilename: {} does not exist", in));
      if (in == recording) throw InputError(fmt::format("{} is being recorded; stop the recording first", in));
      const std::string device = deviceName(c, "OutputVolDeviceName", kDefaultVolumeDevice);
      const std::string file = fileIn(outDir, c, "OutputVolFilename");
      PosedSequence seq = plusConfig.empty() ? openPosedSequence(in, PlusConfig{}) : openPosedSequence(in, plusConfig);
      const Grid g = c.has("OutputExtent") || c.has("OutputSpacing")
                         ? regionOfInterest(c)
                         : gp::chooseGrid(seq, recon, runGrid.spacing, 0.0, false);
      auto r = gp::makeReconstructor(g, recon, memoryLimit, "ReconstructVolume's grid");
      const gp::ReconRunStats st = gp::runReconstruction(seq, *r);
      r->finish();
      const Volume v = r->output().as(ScalarType::U8);
      if (!file.empty()) writeVolume(file, v, true);
      reply(true, fmt::format("reconstructed {} into {} ({}x{}x{} voxels, {} of {} frames){}", in, device, g.dims.x,
                              g.dims.y, g.dims.z, st.inserted, st.frames,
                              file.empty() ? "" : fmt::format(", written to {}", file)));
      server.publishImage(device, v.grid.dims, v.bytes.data(), voxelToReference(v.grid), 0.0);
      return std::nullopt;
    }
    if (n == "StartRecording") {
      if (!recording.empty()) throw InputError(fmt::format("already recording into {}; stop it first", recording));
      std::string path = fileIn(outDir, c, "OutputFilename");
      while (path.empty()) {
        const std::string p = (fs::path(outDir) / fmt::format("recording-{}.mha", ++recordings)).string();
        if (!fs::exists(p)) path = p;
      }
      if (path.size() < 4 || path.compare(path.size() - 4, 4, ".mha") != 0)
        throw InputError("OutputFilename: a recording is a PLUS sequence, .mha");
      if (fs::exists(path)) throw InputError(fmt::format("{} exists; a recording never overwrites a file", path));
      recorder.record(path);
      recording = path;
      recordingOn = true;
      return fmt::format("recording into {}", path);
    }
    if (n == "StopRecording") {
      if (recording.empty()) throw InputError("no recording is under way");
      recorder.record("");
      recorder.finish();
      recordingOn = false;
      return fmt::format("recorded into {}", std::exchange(recording, {}));
    }
    throw InputError(fmt::format("pp5echo does not run this command (it runs StartVolumeReconstruction, "
                                 "SuspendVolumeReconstruction, ResumeVolumeReconstruction, "
                                 "GetVolumeReconstructionSnapshot, StopVolumeReconstruction, ReconstructVolume, "
                                 "StartRecording, StopRecording)"));
  }
};

PlusCommands::PlusCommands(const host::RunJob& job, igtl::Server& server) : impl_(std::make_unique<Impl>(job, server)) {
  impl_->thread = std::thread([i = impl_.get()] { i->run(); });
  server.onCommand([i = impl_.get()](const igtl::Command& c, igtl::CommandReply reply) {
    Impl::Job j;
    j.command = c;
    j.reply = std::move(reply);
    i->push(std::move(j));
  });
}

PlusCommands::~PlusCommands() {
  impl_->server.onCommand({});  // no command reaches this object from now on
  try {
    finish();
  } catch (const std::exception& e) {
    spdlog::error("igtl: {}", e.what());
  }
  {
    const std::lock_guard lock(impl_->m);
    impl_->quit = true;
  }
  impl_->cv.notify_all();
  if (impl_->thread.joinable()) impl_->thread.join();
}

void PlusCommands::frame(const host::AcquiredFrame& a) {
  if (!impl_->reconstructing && !impl_->recordingOn) return;
  Impl::Job j;
  j.isFrame = true;
  j.frame = a;
  impl_->push(std::move(j));
}

void PlusCommands::finish() {
  std::unique_lock lock(impl_->m);
  impl_->finishing = true;  // no more jobs: what the worker holds is this thread's now
  impl_->idle.wait(lock, [&] { return impl_->jobs.empty() && !impl_->busy; });
  lock.unlock();
  // The worker is idle: what it holds may be closed here.
  Impl& i = *impl_;
  if (i.volume) {
    i.reconstructing = false;
    igtl::Command stop;
    stop.name = "StopVolumeReconstruction";
    i.deliver(stop, [](bool, const std::string& message) { spdlog::info("igtl: the input ended: {}", message); }, true,
              "stopped");
    i.volume.reset();
  }
  if (!i.recording.empty()) {
    i.recorder.record("");
    i.recordingOn = false;
    spdlog::info("igtl: the input ended: recorded into {}", std::exchange(i.recording, {}));
  }
  i.recorder.finish();
}

}  // namespace pp5::outputs
