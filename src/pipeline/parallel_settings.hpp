#pragma once
// [parallel]: how `pp5echo run` under mpirun lays the pipeline out on ranks,
// and comm::ControlState conversions (the view, shading, transfer function and live
// composition mode a control change carries). No MPI here.
#include <string>

#include "comm/messages.hpp"
#include "pipeline/schedule.hpp"
#include "core/camera.hpp"
#include "core/enum_names.hpp"
#include "core/render_settings.hpp"
#include "core/transfer_function.hpp"
#include "rendering/shading.hpp"
#include "rendering/ray_cache.hpp"

namespace pp5 {
class ConfigSchema;
}

namespace pp5::parallel {

enum class GpPartition { Slab, Tile };
enum class CompositeOn { Tick, Lockstep };

struct ParallelSettings {
  int gps = 0;                            // graphics processors; 0 = from the world size
  int pps = 0;                            // pixel processors; 0 = max(1, size / 4)
  GpPartition gpPartition = GpPartition::Slab;
  SlabSplit slabSplit = SlabSplit::Longest;
  int ghostVoxels = 1;                    // slab: voxels kept exact around a GP's cells
  int tileSize = 128;                     // screen tile side, pixels
  TileOwnership tileOwner = TileOwnership::Contiguous;
  CompositeOn compositeOn = CompositeOn::Tick;
  double tickHz = 30.0;                   // compositing ticks per second (tick)
  int credits = 4;                        // frames in flight per GP
  int batchFrames = 8;                    // tick: waiting frames a GP updates together
  double timeoutS = 30.0;                 // longest silence before a rank gives up
  int threads = 1;                        // threads per rank (reconstruct, shade, sample, composite)

  bool slab() const { return gpPartition == GpPartition::Slab; }
  bool lockstep() const { return compositeOn == CompositeOn::Lockstep; }
  TileOwnership ownership() const { return tileOwner; }
  SlabSplit split() const { return slabSplit; }
};
void registerOptions(ConfigSchema& schema, ParallelSettings& s);

comm::ControlState makeControlState(const RenderSettings& render, const gp::ShadeSettings& shading,
                              const TransferFunctionSettings& tf);
// Writes the state back into settings (the parts it carries); the live mode
// becomes the first of render.compositing. InputError if the transfer
// function has more points than a control message holds.
void applyControlState(const comm::ControlState& c, RenderSettings& render, gp::ShadeSettings& shading,
                       TransferFunctionSettings& tf);
pp::CompositeMode liveMode(const comm::ControlState& c);
// The camera of a state: makeCamera of its view, then its orbit (if any).
Camera controlCamera(const comm::ControlState& c, const RenderSettings& base, const Grid& grid);
// Which comm::ControlMsg::Change bits differ between two states.
std::uint32_t controlChanges(const comm::ControlState& before, const comm::ControlState& after);

}  // namespace pp5::parallel

namespace pp5 {

template <>
struct EnumNames<parallel::GpPartition> {
  static constexpr std::string_view key = "parallel.gp_partition";
  static constexpr std::array<std::pair<parallel::GpPartition, std::string_view>, 2> names{{
      {parallel::GpPartition::Slab, "slab"},
      {parallel::GpPartition::Tile, "tile"}}};
};

template <>
struct EnumNames<parallel::CompositeOn> {
  static constexpr std::string_view key = "parallel.composite_on";
  static constexpr std::array<std::pair<parallel::CompositeOn, std::string_view>, 2> names{{
      {parallel::CompositeOn::Tick, "tick"},
      {parallel::CompositeOn::Lockstep, "lockstep"}}};
};

}  // namespace pp5
