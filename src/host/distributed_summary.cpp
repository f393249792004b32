// The distributed pipeline's closing report: the critical path of each
// stage over the ranks, the traffic by kind, each rank's load; printed and
// returned as summary.json's text.
#include <algorithm>
#include <cstdio>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "host/distributed_pipeline.hpp"

namespace pp5::host {

using namespace pp5::comm;
using namespace pp5::parallel;

std::string DistributedPipeline::summary(const RunEnd& e) {
  const double streamS = e.streamS, totalS = e.totalS;
  if (!e.orbitMs.empty()) {
    std::vector<double> o = e.orbitMs;
    std::sort(o.begin(), o.end());
    spdlog::info("run: full re-render after a view change (median of {}): {:.0f} ms", o.size(), o[o.size() / 2]);
  }
  std::printf("run: %llu frames through %d ranks (1 host, %d GP, %d PP; %s partition, %s tiles of %d px, %s) in %.1f s\n",
              static_cast<unsigned long long>(sent_), L_.worldSize(), L_.gps, L_.pps,
              enumName(j_.parallel.gpPartition).data(), enumName(j_.parallel.tileOwner).data(), j_.parallel.tileSize,
              enumName(j_.parallel.compositeOn).data(), totalS);
  if (ref_)
    std::printf("  verified: %llu images bitwise equal to the serial pipeline's\n",
                static_cast<unsigned long long>(verified_));
  const std::vector<double> lat = latency_.measured();
  ReportMsg host = makeReport(t_, Role::Host, clock_.total(), totalS, 0, 0, streamCpu_);
  std::vector<ReportMsg> all = reports_;
  all.push_back(host);
  std::sort(all.begin(), all.end(), [](const ReportMsg& a, const ReportMsg& b) { return a.rank < b.rank; });
  std::uint64_t bytes = 0;
  std::uint64_t byKind[kTrafficKinds] = {};
  for (const auto& r : all) {
    bytes += r.bytesSent;
    for (int k = 0; k < kTrafficKinds; ++k) byKind[k] += r.bytesByKind[k];
  }
  const double frames = static_cast<double>(std::max<std::uint64_t>(1, sent_));
  std::string json = "{\n";
  json += fmt::format("  \"ranks\": {}, \"gps\": {}, \"pps\": {},\n", L_.worldSize(), L_.gps, L_.pps);
  json += fmt::format("  \"gp_partition\": \"{}\", \"slab_split\": \"{}\", \"tile_owner\": \"{}\", \"tile_size\": {}, "
                      "\"composite_on\": \"{}\",\n",
                      enumName(j_.parallel.gpPartition), enumName(j_.parallel.slabSplit),
                      enumName(j_.parallel.tileOwner), j_.parallel.tileSize, enumName(j_.parallel.compositeOn));
  json += fmt::format("  \"frames\": {}, \"stream_s\": {:.4f}, \"total_s\": {:.4f},\n", sent_, streamS, totalS);
  json += fmt::format("  \"frames_per_s_in\": {:.3f}, \"images_per_s_out\": {:.3f}, \"dropped_frames\": {},\n",
                      sent_ / streamS, streamImages_ / streamS, e.dropped);
  json += fmt::format("  \"capture_interval_mm\": {:g}, \"frames_left_out_by_interval\": {},\n", e.captureIntervalMm,
                      e.skipped);
  if (!e.sourceStatsJson.empty()) json += fmt::format("  \"source\": {},\n", e.sourceStatsJson);
  json += fmt::format("  \"latency_ms_median\": {:.3f}, \"latency_ms_p95\": {:.3f},\n", percentile(lat, 0.5),
                      percentile(lat, 0.95));
  json += fmt::format("  \"bytes_per_frame\": {:.1f}, \"pixel_messages\": {}, \"pose_only_messages\": {}, "
                      "\"previous_messages\": {},\n",
                      static_cast<double>(bytes) / static_cast<double>(sent_), pixelMessages_, poseOnlyMessages_,
                      previousMessages_);
  // By kind, and the samples split into the frames' incremental updates and
  // the full re-samples after control changes (views, styles, the orbit).
  json += "  \"bytes_per_frame_by_kind\": {";
  for (int k = 0; k < kTrafficKinds; ++k)
    json += fmt::format("{}\"{}\": {:.1f}", k ? ", " : "", kTrafficNames[k], static_cast<double>(byKind[k]) / frames);
  // An incremental frame's traffic: the frame in, its samples, and its
  // image update's tiles (no full images, no final renders).
  const double incremental =
      static_cast<double>(byKind[kTrafficFrames] + incrementalSampleBytes_ + incrementalTileBytes_) / frames;
  json += fmt::format("}},\n  \"incremental_bytes_per_frame\": {{\"total\": {:.1f}, \"frames\": {:.1f}, "
                      "\"samples\": {:.1f}, \"tiles\": {:.1f}}}, \"sample_bytes_full_renders\": {},\n",
                      incremental, static_cast<double>(byKind[kTrafficFrames]) / frames,
                      static_cast<double>(incrementalSampleBytes_) / frames,
                      static_cast<double>(incrementalTileBytes_) / frames, fullSampleBytes_);
  const auto updates = static_cast<std::uint64_t>(std::llround(gpUpdates_));
  json += fmt::format("  \"gp_frame_credits\": {}, \"gp_frame_updates\": {}, \"gp_frames_batched\": {}, "
                      "\"gp_max_batch\": {},\n",
                      frameCredits_, updates, framesBatched_, maxBatch_);
  json += "  \"stages\": {";
  std::printf("  frames/s in %.1f, images/s out %.1f, latency median %.1f ms, p95 %.1f ms, %.0f kB per frame\n",
              sent_ / streamS, streamImages_ / streamS, percentile(lat, 0.5), percentile(lat, 0.95),
              static_cast<double>(bytes) / static_cast<double>(sent_) / 1e3);
  std::printf("  kB per frame: frames %.0f, samples %.0f, tiles %.0f, volume %.0f, control %.0f; an incremental "
              "frame's %.0f (samples %.0f, tiles %.0f)\n",
              static_cast<double>(byKind[kTrafficFrames]) / frames / 1e3,
              static_cast<double>(byKind[kTrafficSamples]) / frames / 1e3,
              static_cast<double>(byKind[kTrafficTiles]) / frames / 1e3,
              static_cast<double>(byKind[kTrafficVolume]) / frames / 1e3,
              static_cast<double>(byKind[kTrafficControl]) / frames / 1e3, incremental / 1e3,
              static_cast<double>(incrementalSampleBytes_) / frames / 1e3,
              static_cast<double>(incrementalTileBytes_) / frames / 1e3);
  std::printf("  GP updates: %llu for %llu frame messages (%llu updated in batches, up to %u frames at once)\n",
              static_cast<unsigned long long>(updates), static_cast<unsigned long long>(frameCredits_),
              static_cast<unsigned long long>(framesBatched_), maxBatch_);
  std::printf("  %-12s %12s %12s %10s\n", "stage", "critical ms", "mean ms", "imbalance");
  for (int s = 0; s < kStageCount; ++s) {
    // The critical path over every rank; the imbalance over the ranks of the
    // role that does the stage (GPs reconstruct, shade and sample; PPs
    // composite; GPs and PPs receive, send and wait), so the host does not
    // skew it.
    const bool gpStage = s == kReconstruct || s == kShade || s == kSample;
    double mx = 0.0, roleMax = 0.0, sum = 0.0;
    int n = 0;
    for (const auto& r : all) {
      mx = std::max(mx, static_cast<double>(r.total.ms[s]));
      const auto role = static_cast<Role>(r.role);
      const bool counts = gpStage ? role == Role::Gp : s == kComposite ? role == Role::Pp : role != Role::Host;
      if (!counts) continue;
      roleMax = std::max(roleMax, static_cast<double>(r.total.ms[s]));
      sum += r.total.ms[s];
      ++n;
    }
    const double mean = n ? sum / n : 0.0;
    const double imbalance = mean > 0 ? roleMax / mean : 0.0;
    json += fmt::format("{}\n    \"{}\": {{\"critical_ms\": {:.3f}, \"mean_ms\": {:.3f}, \"imbalance\": {:.3f}}}",
                        s ? "," : "", stageName(s), mx, mean, imbalance);
    std::printf("  %-12s %12.1f %12.1f %10.2f\n", stageName(s), mx, mean, imbalance);
  }
  json += "\n  },\n  \"per_rank\": [";
  std::printf("  %-5s %-5s %9s %9s %12s %12s\n", "rank", "role", "cpu s", "wall s", "MB sent", "MB received");
  for (std::size_t i = 0; i < all.size(); ++i) {
    const ReportMsg& r = all[i];
    json += fmt::format("{}\n    {{\"rank\": {}, \"role\": \"{}\", \"cpu_s\": {:.4f}, \"wall_s\": {:.4f}, "
                        "\"bytes_sent\": {}, \"bytes_received\": {}, \"messages_sent\": {}, \"messages_received\": {}, "
                        "\"dropped_messages\": {}, \"memory_bytes\": {}, \"stream_cpu_s\": {:.4f}, \"stream_bytes\": {}",
                        i ? "," : "", r.rank, roleName(static_cast<Role>(r.role)), r.cpuS, r.wallS, r.bytesSent,
                        r.bytesReceived, r.messagesSent, r.messagesReceived, r.dropped, r.memoryBytes, r.streamCpuS,
                        r.streamBytes);
    json += ", \"stage_ms\": {";
    for (int s = 0; s < kStageCount; ++s) json += fmt::format("{}\"{}\": {:.3f}", s ? ", " : "", stageName(s), r.total.ms[s]);
    json += "}}";
    std::printf("  %-5u %-5s %9.2f %9.2f %12.1f %12.1f\n", r.rank, roleName(static_cast<Role>(r.role)), r.cpuS, r.wallS,
                static_cast<double>(r.bytesSent) / 1e6, static_cast<double>(r.bytesReceived) / 1e6);
  }
  json += "\n  ]\n}\n";
  return json;
}

}  // namespace pp5::host
