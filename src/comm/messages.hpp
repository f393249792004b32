#pragma once
// Every message of the distributed pipeline, in one place (docs/protocol.md).
//
// A message is one MPI message: a fixed, trivially copyable struct that
// starts with a Header, then (for some tags) a payload of plain values whose
// length follows from the struct. Nothing holds a pointer. Each message
// carries the frame and epoch it belongs to: the epoch grows with every
// control change the host broadcasts (view, shading, transfer function,
// composition mode, the end of input), and a message from an older epoch than
// the receiver's is recognised and dropped.
//
// Frame numbers are the host's stream positions (0, 1, 2, ... of the frames
// it sent), not the source's indices, so a dropped live frame leaves no gap.
#include <cstddef>
#include <cstdint>
#include <type_traits>

#include "core/ray_sample.hpp"
#include "core/view_state.hpp"

namespace pp5::comm {

// MPI tags. Each says why the message exists.
enum Tag : int {
  // host -> GP: a frame to reconstruct, or (slab, not touched) its pose only,
  // so that the GP's fill-in and motion state advance as the serial one's.
  // Costs one credit of the receiving GP.
  kTagFrame = 1,
  // host -> GP (slab): the pixels of the previous frame, which the GP got
  // pose-only, because the fill-in from it to the next frame reaches the GP.
  kTagPrevious = 2,
  // host -> GP, PP: new view, shading, transfer function or composition mode
  // (or the end of input), with the new epoch; everything is re-sampled.
  kTagControl = 3,
  // GP -> host: a frame (or control change) done, one credit back, with the
  // GP's timers for it.
  kTagCredit = 4,
  // GP -> PP: the ray samples of one screen tile from one frame.
  kTagSamples = 5,
  // GP -> PP: every sample batch of a frame (or of a full re-sample) sent;
  // a PP knows an update is complete by counting these, one per GP.
  kTagGpDone = 6,
  // PP -> host: the changed pixels of one tile (float RGBA, premultiplied).
  kTagTile = 7,
  // PP -> host: an image update done (lockstep: one per frame; tick mode: one
  // per tick that changed something), after its tiles.
  kTagPpDone = 8,
  // host -> PP: composite every tile in full in one mode and send it (the
  // final images in each configured mode).
  kTagRequest = 9,
  // host -> GP: send your part of the reconstructed volume.
  kTagVolumeRequest = 10,
  // GP -> host: a run of z planes of its part of the reconstructed volume.
  kTagVolume = 11,
  // host -> GP, PP: the job is over; report and exit.
  kTagQuit = 12,
  // GP, PP -> host: transport counters and timer totals, the last message.
  kTagReport = 13,
  // host -> every rank, once, by broadcast before the ranks start: the
  // reconstruction grid, which only the host's source knows (its extent comes
  // from the frames it reads or simulates).
  kTagGrid = 14,
  // host -> GP, PP (EmptyMsg): nothing to do, the host is alive. Sent every
  // quarter of parallel.timeout_s while the host's loop runs (a quiet live
  // source, acquisition paused, the final volume served), so that no rank's
  // parallel.timeout_s runs out while there is simply nothing to do.
  kTagKeepAlive = 15,
  // GP, PP -> host (EmptyMsg): the answer to a keep-alive, the ranks'
  // heartbeat. A quiet source is then told apart from a rank that died or
  // stopped, and the host names the rank whose heartbeat stopped.
  kTagAlive = 16,
};

// What the bytes a rank sends are for (summary.json's bytes_by_kind): the
// frames in, the ray samples, the image tiles out, the reconstructed volume,
// and everything else (control, credits, requests, reports).
enum Traffic : int { kTrafficFrames, kTrafficSamples, kTrafficTiles, kTrafficVolume, kTrafficControl, kTrafficKinds };
inline constexpr const char* kTrafficNames[kTrafficKinds] = {"frames", "samples", "tiles", "volume", "control"};
constexpr Traffic trafficOf(int tag) {
  switch (tag) {
    case kTagFrame:
    case kTagPrevious: return kTrafficFrames;
    case kTagSamples:
    case kTagGpDone: return kTrafficSamples;
    case kTagTile:
    case kTagPpDone: return kTrafficTiles;
    case kTagVolume: return kTrafficVolume;
    default: return kTrafficControl;
  }
}

struct Header {
  std::uint32_t tag = 0;
  std::uint32_t epoch = 0;
  std::uint64_t frame = 0;
};

// The per-stage timers every rank keeps (docs/protocol.md, stats.csv).
enum Stage : int { kReceive, kReconstruct, kShade, kSample, kSend, kWait, kComposite, kStageCount };
inline const char* stageName(int s) {
  static const char* const names[kStageCount] = {"receive", "reconstruct", "shade", "sample",
                                                 "send",    "wait",        "composite"};
  return names[s];
}
struct StageTimes {
  float ms[kStageCount] = {};
};

// kTagFrame. Payload: height * width * bytesPerPixel pixel bytes (none when
// poseOnly), row-major.
struct FrameMsg {
  Header h;
  std::uint64_t sourceIndex = 0;  // the frame's index in its source
  double timeS = 0.0;             // the frame's timestamp, seconds
  double imageToReference[16] = {};  // row-major, mm
  std::int32_t width = 0, height = 0;
  std::uint8_t pixelType = 0;   // core::PixelType
  std::uint8_t poseOnly = 0;    // 1: no pixels (slab: the frame cannot reach this GP)
  std::uint8_t pad[6] = {};
};

// kTagPrevious. Payload: the pixels of frame h.frame (sent earlier pose-only).
struct PreviousMsg {
  Header h;
  std::int32_t width = 0, height = 0;
  std::uint8_t pixelType = 0;
  std::uint8_t pad[7] = {};
};

// What a control change carries: the view state the user steers
// (core/view_state.hpp), whole, so a receiver needs no history.
using ControlState = ViewState;

// kTagControl.
struct ControlMsg {
  Header h;  // h.epoch: the new epoch; h.frame: the last frame sent before it
  enum Change : std::uint32_t {
    kView = 1,        // new lattice, new caches
    kShading = 2,     // re-shade
    kTransfer = 4,    // re-shade
    kMode = 8,        // the PPs recomposite in the new live mode; GPs do nothing
    kFinish = 16,     // end of input: the reconstruction's final passes, then re-shade
  };
  // Changes that can change a voxel's opacity: every voxel is re-shaded.
  static constexpr std::uint32_t kReshade = kShading | kTransfer | kFinish;
  // Changes after which every sample is made anew (new caches); a view
  // change alone re-lights only the visible voxels.
  static constexpr std::uint32_t kResample = kView | kReshade;
  std::uint32_t changes = 0;
  // 1: frames were sent before it, h.frame the last of them. In tick mode a
  // PP applies the change only once every GP has finished those frames, and
  // shows them in the old view first.
  std::uint32_t afterFrame = 0;
  ControlState state;
};

// kTagCredit.
struct CreditMsg {
  Header h;
  std::uint32_t gp = 0;
  std::uint32_t isControl = 0;  // 1: for a control change, not a frame
  StageTimes times;             // this frame's (or change's) time per stage
  std::uint32_t batch = 1;      // frames in the GP update that included this one (tick mode batches waiting frames)
  std::uint64_t samples = 0;    // samples sent for it
  std::uint64_t bytesSent = 0;  // bytes sent for it
  std::uint64_t dirtyVoxels = 0;
};

// kTagSamples. Payload: count RaySamples, all in tile `tile`.
struct SamplesMsg {
  Header h;
  std::uint32_t gp = 0;
  std::uint32_t tile = 0;
  std::uint64_t count = 0;
};

// kTagGpDone.
struct GpDoneMsg {
  Header h;
  std::uint32_t gp = 0;
  std::uint32_t batches = 0;  // kTagSamples messages sent to this PP for it
  std::uint64_t samples = 0;
  std::uint32_t full = 0;     // 1: a full re-sample (the PP cleared its caches for it)
  std::uint32_t pad = 0;
};

// kTagTile. Payload: width * height * 4 floats, premultiplied RGBA, row-major.
struct TileMsg {
  Header h;
  std::int32_t x0 = 0, y0 = 0, width = 0, height = 0;  // in the whole image
  std::uint8_t mode = 0;     // pp::CompositeMode of these pixels
  std::uint8_t request = 0;  // 1: part of the answer to a kTagRequest, not the live image
  std::uint8_t pad[6] = {};
};

// kTagPpDone.
struct PpDoneMsg {
  Header h;  // h.frame: every frame up to this one is in the tiles sent
  std::uint32_t pp = 0;
  std::uint32_t tiles = 0;   // kTagTile messages sent for this update
  std::uint32_t request = 0;  // 1: the answer to a kTagRequest
  std::uint32_t full = 0;     // 1: every tile was sent (new caches after a control change)
  StageTimes times;           // since the last PpDone
  std::uint64_t rays = 0, blocks = 0, samplesPut = 0;
  std::uint64_t tileBytes = 0;  // bytes of the tiles kind (Tile and PpDone messages) since the last PpDone
};

// kTagRequest.
struct RequestMsg {
  Header h;
  std::uint8_t mode = 0;  // pp::CompositeMode
  std::uint8_t pad[7] = {};
};

// kTagVolumeRequest, kTagQuit: a Header alone.
struct EmptyMsg {
  Header h;
};

// kTagVolume. Payload: `boxes` VolumeBox, then the voxels of each box in
// turn, in the reconstruction's voxel type, x fastest.
struct VolumeMsg {
  Header h;
  std::uint32_t gp = 0;
  std::uint32_t last = 0;        // 1: the GP's last piece
  std::uint32_t scalarType = 0;  // core ScalarType of the payload
  std::uint32_t boxes = 0;       // how many boxes this piece holds
};
// A voxel box [lo, hi) of a VolumeMsg.
struct VolumeBox {
  std::int64_t lo[3] = {}, hi[3] = {};
};

// kTagReport.
struct ReportMsg {
  Header h;
  std::uint32_t rank = 0;
  std::uint32_t role = 0;  // parallel::Role
  StageTimes total;        // whole run, per stage
  double cpuS = 0.0;       // process CPU time (user + system)
  double wallS = 0.0;
  double streamCpuS = 0.0;  // of cpuS, what the stream of frames took (parallel::StreamCpu)
  std::uint64_t streamBytes = 0;  // bytes sent and received meanwhile
  std::uint64_t bytesSent = 0, bytesReceived = 0, messagesSent = 0, messagesReceived = 0;
  std::uint64_t dropped = 0;  // messages of an older epoch dropped
  std::uint64_t memoryBytes = 0;  // the main buffers (grid, shade buffer, caches)
  std::uint64_t bytesByKind[kTrafficKinds] = {};  // bytesSent by Traffic
};

// kTagGrid (broadcast): what only the host's source knows before the run.
struct GridMsg {
  Header h;
  std::int64_t dims[3] = {};
  double origin[3] = {}, spacing[3] = {};  // mm
  // The tent kernel's half-widths (lateral, axial, elevation), mm: derived
  // from a recording on the host (recon.kernel_from_frames) or as configured.
  double kernelMm[3] = {};
};

template <typename T>
inline constexpr bool kIsMessage = std::is_trivially_copyable_v<T> && std::is_standard_layout_v<T> &&
                                   offsetof(T, h) == 0;
static_assert(kIsMessage<FrameMsg> && kIsMessage<PreviousMsg> && kIsMessage<ControlMsg> && kIsMessage<CreditMsg> &&
              kIsMessage<SamplesMsg> && kIsMessage<GpDoneMsg> && kIsMessage<TileMsg> && kIsMessage<PpDoneMsg> &&
              kIsMessage<RequestMsg> && kIsMessage<EmptyMsg> && kIsMessage<VolumeMsg> && kIsMessage<ReportMsg> &&
              kIsMessage<GridMsg>);
static_assert(std::is_trivially_copyable_v<VolumeBox> && sizeof(VolumeBox) == 48);
static_assert(sizeof(RaySample) == 24);

}  // namespace pp5::comm
