#pragma once
// The predictive cost model of `pp5echo bench --cost-model` (issue 17):
//  1. a census of the sweep, counted once on the serial pipeline
//     (pipeline/work_census.hpp), says where its work lies;
//  2. rankWork() gives each rank of any layout its share of that work: the
//     frames it handles, the voxels it reconstructs, the dirty voxels its
//     change tracker scans, the samples it makes or receives, the frame
//     bytes the host sends, with the layout's real slab cuts and tile owners;
//  3. fitCosts() fits per-unit CPU costs by role (least squares, the costs
//     kept non-negative) to the CPU seconds each rank of some layouts spent
//     on the stream of frames (summary.json's stream_cpu_s: start-up and the
//     final pass left out);
//  4. predict() gives another layout's ranks their CPU seconds and the
//     frames/s this machine sustains: the stream takes as long as the busiest
//     rank's CPU, or the sum of every rank's over the cores, whichever is
//     longer; and the frames/s of one rank per core on a cluster, each rank
//     also moving its bytes over a link.
#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "benchmark/layouts.hpp"

namespace pp5::harness {

struct Census {
  std::array<std::int64_t, 3> dims{};
  int width = 0, height = 0, binPx = 0, binsX = 0, binsY = 0;
  double frames = 0.0, framePixelBytes = 0.0;
  std::array<std::vector<double>, 3> recon, shaded;  // [axis][voxel layer]
  std::array<std::vector<double>, 3> samples;        // [axis][bin * cells + cell layer]
  std::vector<std::array<std::int64_t, 6>> frameRanges;
  struct Footprint {
    int x0, y0, x1, y1;  // bins, inclusive
    double voxels;
  };
  std::vector<Footprint> footprints;
};
// InputError naming the file and what is wrong.
Census readCensus(const std::string& path);

enum class RankRole { Host, Gp, Pp };

// One rank's share of the sweep's work.
struct RankWork {
  RankRole role = RankRole::Host;
  double frames = 0;        // frame messages handled (with pixels or pose only)
  double pixelFrames = 0;   // host: frame messages with pixels sent; GP: received
  double pixelBytes = 0;    // the same in bytes
  double reconVoxels = 0;   // GP: dirty voxels reconstructed
  double scanVoxels = 0;    // GP: dirty voxels its change tracker scans
  double samples = 0;       // GP: samples made; PP: samples received
  double ownedTiles = 0;    // PP: its share of the screen's tiles (0..1)
};
// Ranks in MPI order: the host, the GPs, the PPs. InputError for a layout the
// census cannot split (a tile size that is not a multiple of its bins). It
// splits as parallel.slab_split = "longest", parallel.ghost_voxels = 1 and the
// tent kernel do, and gives a slab GP the frames whose dirty range meets its
// window (the host routes by the frame's reach, a little wider).
std::vector<RankWork> rankWork(const Census& c, const Layout& l);

// What one rank of a measured layout spent.
struct Observation {
  Layout layout;
  std::vector<double> cpuS;        // per rank, the stream's CPU (summary.json's stream_cpu_s)
  std::vector<double> bytesMoved;  // per rank, sent + received during the stream (summary.json's stream_bytes)
  double streamS = 0.0;            // the stream's wall time (frames / frames_per_s_in)
  double framesPerS = 0.0;
};

// Per-unit CPU seconds by role. The PP's "per second of stream" is what its
// 30 Hz ticks cost however little arrives. (A GP or the host gets no such
// term: on a shared machine their CPU and the stream's length grow together,
// and the fit would explain the one by the other.)
struct UnitCosts {
  // GP: per frame, per reconstructed voxel, per scanned voxel, per sample, per TCP byte.
  std::array<double, 5> gp{};
  // PP: per sample received, per second of stream and whole screen owned (the ticks' compositing), per second
  // of stream, per TCP byte.
  std::array<double, 4> pp{};
  // host: per frame, per pixel byte, per TCP byte.
  std::array<double, 3> host{};
  // Bytes each GP sends per sample, each PP sends per second of stream and whole screen.
  double bytesPerSample = 0.0, tileBytesPerS = 0.0;
  std::array<double, 3> rmsResidualS{};  // the fit's, per role (host, GP, PP)
  std::size_t observations = 0;
};
UnitCosts fitCosts(const Census& c, std::span<const Observation> obs);

struct Prediction {
  std::vector<double> rankCpuS;  // per rank, the stream's CPU
  std::vector<double> rankBytes;  // per rank, bytes sent + received
  double streamS = 0.0, framesPerS = 0.0;
  int busiest = 0;        // the rank with the most CPU
  bool coreBound = false;  // the cores, not one rank, set the pace
  // false: the PPs' per-second costs grow faster than the stream (their
  // fitted rates sum to a core or more), and no stream length settles them.
  bool converged = false;
};
// This machine: `cores` cores shared by every rank.
Prediction predict(const Census& c, const Layout& l, const UnitCosts& u, int cores);
// One rank per core (any number of nodes): each rank's CPU plus its bytes over
// a link of `bytesPerS`, not overlapped; frames/s and the rank that sets them.
struct ClusterRate {
  double framesPerS = 0.0;
  int limit = 0;
};
ClusterRate clusterRate(const Census& c, const Prediction& p, double bytesPerS);

const char* roleName(RankRole r);

}  // namespace pp5::harness
