#pragma once
// The outputs of a run, as sinks: the mirror of the sources. The one run loop
// (host/run_loop.hpp) hands every sink what the pipeline makes, in the same
// order whichever pipeline it drives; a sink overrides what it wants and
// ignores the rest. The sinks themselves live in outputs/ (files, statistics,
// the live viewer), registered in outputs/sinks.cpp.
//
// A sink's calls come on the loop's thread and must return soon: a sink that
// does slow work (JPEG encoding, a browser's socket) hands it to a thread of
// its own and keeps the newest, so that no sink ever slows the pipeline.
#include <cstdint>
#include <string>
#include <vector>

#include "host/pipeline.hpp"

namespace pp5::host {

// What every sink learns before the first frame.
struct RunStart {
  Grid grid;
  int width = 0, height = 0;  // the image
  ViewState state;            // the initial view
  std::vector<std::string> statsColumns;
};

// The run's figures, as the loop measures them (every 250 ms).
struct LiveFigures {
  double framesPerS = 0, imagesPerS = 0, latencyMedianMs = 0, latencyP95Ms = 0;
  std::uint64_t frames = 0, dropped = 0;
  double gpLoad = 0, ppLoad = 0;  // share of the wall time the GPs (PPs) were busy, 0..1
};

// What a steering sink (the viewer) asks of the pipeline now.
struct LiveWanted {
  ViewState state;  // the view, shading, transfer function and live mode
  bool paused = false;
  bool recording = false;
};

// A sink through which the user steers the run.
class Steering {
public:
  virtual ~Steering() = default;
  // Changes whenever wanted() may have (asked often, without a lock).
  virtual std::uint64_t version() const = 0;
  virtual LiveWanted wanted() const = 0;
  // A newcomer with no image yet: the loop hands over the current one.
  virtual bool wantsImage() const = 0;
  // Whether the final volume stays steerable after the run's own work, until Ctrl-C.
  virtual bool servesFinal() const = 0;
  // From now on the user steers the final volume.
  virtual void servingFinal() = 0;
};

class Sink {
public:
  virtual ~Sink() = default;
  virtual void start(const RunStart& r) { (void)r; }
  // Frame k went into the pipeline.
  virtual void frame(const AcquiredFrame& a, std::uint64_t k) { (void)a, (void)k; }
  // The pipeline renders `state` as `epoch` from now on (lasting: see Pipeline::control).
  virtual void epochStarted(std::uint32_t epoch, const ViewState& state, bool lasting) {
    (void)epoch, (void)state, (void)lasting;
  }
  virtual void image(const ImageView& im) { (void)im; }
  virtual void stats(const std::vector<double>& row) { (void)row; }
  // A snapshot of the growing volume, asked for while the input runs; it
  // holds the first `frames` frames (those frame() was given with k < frames).
  virtual bool wantsVolume() const { return false; }
  // `changed`: where it may differ from the snapshot this sink was given before.
  virtual void volume(const Volume& v, std::uint64_t frames, const VolumeChange& changed) {
    (void)v, (void)frames, (void)changed;
  }
  virtual void figures(const LiveFigures& f) { (void)f; }
  virtual void inputEnded() {}
  // After the final passes: the image of every frame.
  virtual void finished(const ImageView& im) { (void)im; }
  // The final image in each composition mode of render.compositing.
  virtual void finalImage(pp::CompositeMode mode, const ImageView& im) { (void)mode, (void)im; }
  // The final reconstruction.
  virtual bool wantsFinalVolume() const { return false; }
  virtual void finalVolume(const Volume& v) { (void)v; }
  // View `i` of `n` of the rotating loop.
  virtual void orbit(int i, int n, const ImageView& im) { (void)i, (void)n, (void)im; }
  // The pipeline's run summary (JSON; none for the one-process run).
  virtual void summary(const std::string& json) { (void)json; }
  // Every part has stopped: close what is open.
  virtual void ended() {}
  // The files it wrote, for the closing list.
  virtual std::vector<std::string> wrote() const { return {}; }
  virtual Steering* steering() { return nullptr; }
};

}  // namespace pp5::host
