#pragma once
// The live viewer on the host (issue 16): what the pipeline makes, streamed to
// browsers while it makes it, and what the browsers change, handed back to
// the pipeline.
//
// The host's thread only hands things over (a copy, under a lock, and only
// while a browser watches); a thread of the viewer's own turns them into
// JPEGs and messages, so the pipeline never waits for a browser. Each
// browser gets the newest message of each kind (viewer/viewer_server.hpp).
//
// The page and its protocol: src/viewer/web/, docs/viewer.md and
// docs/protocol.md ("The viewer's protocol").
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "comm/messages.hpp"
#include "core/frame.hpp"
#include "core/grid.hpp"
#include "core/render_settings.hpp"
#include "core/transfer_function.hpp"
#include "core/transform.hpp"
#include "formats/volume_io.hpp"
#include "reconstruction/reconstruction.hpp"
#include "host/sink.hpp"
#include "host/view_settings.hpp"

namespace pp5 {
class ConfigSchema;
}

namespace pp5::host {


class LiveView {
public:
  using Clock = std::chrono::steady_clock;
  // Starts serving (InputError when the address cannot be bound, or is not
  // loopback and no token can be had). `initial`: the run's control state;
  // `base`: the render settings it applies to; recordings the page asks for
  // go to `recordDir`/recording-N.mha.
  LiveView(const ViewSettings& settings, const Grid& grid, const RenderSettings& base, const gp::ReconSettings& recon,
           const TransferFunctionSettings& tf, const comm::ControlState& initial, const std::string& recordDir);
  ~LiveView();
  LiveView(const LiveView&) = delete;
  LiveView& operator=(const LiveView&) = delete;

  std::string url() const;
  bool watched() const;  // a browser is connected
  bool serve() const;

  // ---- from the pipeline (the host's thread) ----
  // Frame k went into the pipeline: coverage, the outline, the gap warning,
  // the B-mode view, and the page's recording (written here, on the caller's
  // thread: with its ImageToReference and time).
  void frame(const Frame& f, const Mat4& imageToReference, std::uint64_t k, double timeS, Clock::time_point arrival);
  // The pipeline now renders `state` as `epoch`. `lasting` = false for a
  // change of the run's own that it undoes (a final image of another mode,
  // the orbit): the page's next change is not built on it.
  void epochStarted(std::uint32_t epoch, const comm::ControlState& state, bool lasting = true);
  // The image (width * height RGBA floats, premultiplied) holding every frame
  // up to `frame`, in `epoch`'s view.
  void image(const std::vector<float>& rgba, int width, int height, std::uint32_t epoch, std::int64_t frame);
  // Whether a browser came that has no image yet: the caller hands over the current one.
  bool wantsImage() const;
  // Whether the slices want a newer volume; volume() hands one over (copied).
  bool wantsVolume() const;
  void volume(const Volume& v);
  void figures(const LiveFigures& f);
  void inputEnded();  // also closes a recording
  // The run's own work after the input (final passes and images, the orbit)
  // is done: from now on the page steers the final volume.
  void servingFinal();

  // ---- to the pipeline ----
  LiveWanted wanted() const;
  // Changes whenever wanted() may have: the host's loop asks this (no lock)
  // and fetches wanted() only then.
  std::uint64_t version() const;

  // For tests: applies a control message as if a browser had sent it;
  // returns "" or the error the browser would get.
  std::string control(const std::string& json);

  struct Impl;

private:
  std::unique_ptr<Impl> impl_;
};

// The transfer function's opacity as a ramp: 0 below level - window / 2,
// `opacity` above level + window / 2, linear between (clipped to 0..255).
std::vector<glm::dvec4> rampOpacity(double level, double window, double opacity);

}  // namespace pp5::host
