#include "analysis/recording.hpp"

#include <optional>

#include <fmt/format.h>

#include "core/error.hpp"
#include "formats/sequence_io.hpp"
#include "core/threads.hpp"

namespace pp5::calib {

NWirePhantom phantomOf(const PlusConfig& cfg) {
  if (!cfg.calibrationError.empty()) throw InputError(cfg.calibrationError);
  if (!cfg.phantomDefinition)
    inputError(cfg.path, "no <PhantomDefinition>: a probe calibration needs the N-wire phantom's geometry");
  if (!cfg.segmentation)
    inputError(cfg.path, "no <Segmentation>: a probe calibration needs the wire segmentation's parameters");
  return NWirePhantom(cfg.phantomDefinition->patterns);
}

std::optional<Mat4> phantomToProbe(const PlusConfig& cfg, const Frame& f) {
  TransformRepository repo = cfg.coordinates;
  for (const auto& t : f.transforms) {
    const auto names = splitTransformName(t.name);
    if (!names) continue;
    repo.set(names->first, names->second, t.matrix, t.valid);
  }
  const auto& fr = cfg.probeCalibrationFrames;
  return repo.get(fr.phantom, fr.probe);
}

SegmentedRecording segmentRecording(const std::string& path, const PlusConfig& cfg, int threads,
                                    const std::function<void(const Frame&, const WireSegmentation&)>& onFrame,
                                    const std::function<void(std::size_t, std::size_t)>& progress) {
  const NWirePhantom phantom = phantomOf(cfg);
  auto reader = SequenceReader::open(path);
  const SequenceInfo& info = reader->info();
  if (info.pixelType != PixelType::U8)
    inputError(path, "the frames are 16-bit; a calibration recording is 8-bit B-mode");
  SegmentedRecording rec;
  rec.path = path;
  rec.width = info.width;
  rec.height = info.height;
  rec.frames = info.frameCount;
  // The chain must exist for a frame with valid poses: check it on the first
  // frame's transform names, so a config for another setup fails at once.
  if (info.frameCount > 0) {
    Frame meta = reader->metadata(0);
    for (auto& t : meta.transforms) t.valid = true;
    if (!phantomToProbe(cfg, meta)) {
      std::string names;
      for (const auto& t : meta.transforms) names += (names.empty() ? "" : ", ") + t.name;
      inputError(path, "no chain of transforms from {} to {} through the sequence's ({}) and the config's ({})",
                 cfg.probeCalibrationFrames.phantom, cfg.probeCalibrationFrames.probe, names.empty() ? "none" : names,
                 cfg.path);
    }
  }
  const int nThreads = resolveThreads(threads);
  const std::size_t batch = static_cast<std::size_t>(std::max(8, 4 * nThreads));
  std::vector<Frame> frames(batch);
  std::vector<WireSegmentation> segs(batch);
  std::size_t done = 0;
  for (;;) {
    std::size_t n = 0;
    while (n < batch && reader->next(frames[n])) ++n;
    if (n == 0) break;
#pragma omp parallel for num_threads(nThreads) schedule(dynamic, 1)
    for (std::ptrdiff_t i = 0; i < static_cast<std::ptrdiff_t>(n); ++i) {
      const Frame& f = frames[static_cast<std::size_t>(i)];
      segs[static_cast<std::size_t>(i)] =
          f.imageValid ? segmentWires(f, *cfg.segmentation, phantom) : WireSegmentation{};
    }
    for (std::size_t i = 0; i < n; ++i) {
      const Frame& f = frames[i];
      WireSegmentation& s = segs[i];
      if (!f.imageValid) s.why = "image status INVALID";
      if (onFrame) onFrame(f, s);
      if (!f.imageValid) {
        rec.missed.emplace_back(f.index, s.why);
        continue;
      }
      if (!s.found) {
        rec.missed.emplace_back(f.index, "pattern not found: " + s.why);
        continue;
      }
      const auto pose = phantomToProbe(cfg, f);
      if (!pose) {
        rec.missed.emplace_back(f.index, "a pose on the Phantom to Probe chain is INVALID");
        continue;
      }
      if (!isFinite(*pose)) {
        rec.missed.emplace_back(f.index, "the pose is not finite");
        continue;
      }
      rec.found.push_back({static_cast<std::size_t>(f.index), *pose, s.patterns});
    }
    done += n;
    if (progress) progress(done, rec.frames);
  }
  return rec;
}

}  // namespace pp5::calib
