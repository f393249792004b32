#include "pipeline/parallel_settings.hpp"

#include <cstring>

#include <fmt/format.h>

#include "core/config.hpp"
#include "core/error.hpp"

namespace pp5::parallel {

void registerOptions(ConfigSchema& schema, ParallelSettings& s) {
  schema.section("parallel", "The distributed pipeline under mpirun: ranks, partitionings, tiles and compositing.");
  schema.option("parallel.gps", &s.gps, 0, 0, 4096,
                "Graphics processors (ranks 1..G); 0 = the world size less the host and the pixel processors.");
  schema.option("parallel.pps", &s.pps, 0, 0, 4096, "Pixel processors (ranks G+1..G+P); 0 = max(1, world size / 4).");
  enumOption(schema, "parallel.gp_partition", &s.gpPartition, GpPartition::Slab,
                "How GPs share the work: slab = each owns a box of the grid (object space); tile = each "
                "reconstructs the whole grid and samples only its own screen tiles (screen space).");
  enumOption(schema, "parallel.slab_split", &s.slabSplit, SlabSplit::Longest,
                "slab: cut the grid along its longest axis, or into a 3D grid of boxes closest to cubes.");
  schema.option("parallel.ghost_voxels", &s.ghostVoxels, 1, 1, 64,
                "slab: voxels a GP keeps exact around its box (1 is what the shading gradient needs).");
  schema.option("parallel.tile_size", &s.tileSize, 128, 8, 4096,
                "Screen tile side in pixels (128: a Pixel-Planes 5 renderer); a multiple of 8.");
  enumOption(schema, "parallel.tile_owner", &s.tileOwner, TileOwnership::Contiguous,
                "Which PP (and, for gp_partition = tile, which GP) owns a tile: runs of tiles, or tile id mod count.");
  enumOption(schema, "parallel.composite_on", &s.compositeOn, CompositeOn::Tick,
                "tick: PPs composite on a fixed clock and send what changed; lockstep: after every frame, and "
                "the host waits for each image (deterministic, for tests).");
  schema.option("parallel.tick_hz", &s.tickHz, 30.0, 1.0, 1000.0, "Compositing ticks per second (composite_on = tick).");
  schema.option("parallel.credits", &s.credits, 4, 1, 1024,
                "Frames the host may have in flight to each GP before it waits (flow control).");
  schema.option("parallel.batch_frames", &s.batchFrames, 8, 1, 1024,
                "tick: a GP reconstructs up to this many frames that are already waiting, then shades, samples "
                "and sends their union once (1 = one update per frame). Same final images; lockstep always "
                "updates per frame.");
  schema.option("parallel.timeout_s", &s.timeoutS, 30.0, 0.5, 86400.0,
                "A rank that hears nothing for this long ends the job with a message naming what it waited for.");
  schema.option("parallel.threads", &s.threads, 1, 0, 1024,
                "Threads per rank for reconstruction, shading, sampling and compositing; 0 = every core.");
}

comm::ControlState makeControlState(const RenderSettings& r, const gp::ShadeSettings& sh,
                              const TransferFunctionSettings& tf) {
  comm::ControlState c;
  c.projection = r.projection == Projection::Orthographic ? 1 : 0;
  c.liveMode = static_cast<std::uint8_t>(checkedEnum(r.compositing.front()));
  c.shadeMode = static_cast<std::uint8_t>(sh.mode);
  c.light = static_cast<std::uint8_t>(sh.light);
  c.gradientOpacity = sh.gradientOpacity ? 1 : 0;
  c.fovDeg = r.fovDeg;
  c.azimuthDeg = r.azimuthDeg;
  c.elevationDeg = r.elevationDeg;
  c.distance = r.distance;
  c.stepScale = r.stepScale;
  c.pixelStride = static_cast<std::uint8_t>(r.pixelStride);
  c.panMm[0] = r.panMm[0];
  c.panMm[1] = r.panMm[1];
  c.valueWindow[0] = r.valueWindow[0];
  c.valueWindow[1] = r.valueWindow[1];
  c.ambient = sh.ambient;
  c.diffuse = sh.diffuse;
  c.specular = sh.specular;
  c.shininess = sh.shininess;
  for (int i = 0; i < 3; ++i) c.lightDirection[i] = sh.lightDirection[i];
  c.flatGradient = sh.flatGradient;
  c.gradientOpacityLow = sh.gradientOpacityLow;
  c.gradientOpacityWidth = sh.gradientOpacityWidth;
  if (tf.opacity.size() > comm::ControlState::kMaxPoints || tf.colour.size() > comm::ControlState::kMaxPoints)
    throw InputError(fmt::format("render.tf: at most {} opacity and {} colour points fit in a control message",
                                 comm::ControlState::kMaxPoints, comm::ControlState::kMaxPoints));
  c.opacityPoints = static_cast<std::int32_t>(tf.opacity.size());
  c.colourPoints = static_cast<std::int32_t>(tf.colour.size());
  for (std::size_t i = 0; i < tf.opacity.size(); ++i) {
    c.opacity[i][0] = tf.opacity[i][0];
    c.opacity[i][1] = tf.opacity[i][1];
  }
  for (std::size_t i = 0; i < tf.colour.size(); ++i)
    for (int j = 0; j < 4; ++j) c.colour[i][j] = tf.colour[i][j];
  return c;
}

void applyControlState(const comm::ControlState& c, RenderSettings& r, gp::ShadeSettings& sh, TransferFunctionSettings& tf) {
  r.projection = c.projection ? Projection::Orthographic : Projection::Perspective;
  r.fovDeg = c.fovDeg;
  r.azimuthDeg = c.azimuthDeg;
  r.elevationDeg = c.elevationDeg;
  r.distance = c.distance;
  r.stepScale = c.stepScale;
  r.pixelStride = c.pixelStride;
  r.panMm[0] = c.panMm[0];
  r.panMm[1] = c.panMm[1];
  r.valueWindow = glm::dvec2(c.valueWindow[0], c.valueWindow[1]);
  const CompositeMode live = liveMode(c);
  std::erase(r.compositing, live);
  r.compositing.insert(r.compositing.begin(), live);
  sh.mode = checkedEnum(static_cast<gp::ShadeMode>(c.shadeMode));
  sh.light = static_cast<gp::LightKind>(c.light) == gp::LightKind::Direction ? gp::LightKind::Direction : gp::LightKind::Viewer;
  sh.gradientOpacity = c.gradientOpacity != 0;
  sh.ambient = c.ambient;
  sh.diffuse = c.diffuse;
  sh.specular = c.specular;
  sh.shininess = c.shininess;
  for (int i = 0; i < 3; ++i) sh.lightDirection[i] = c.lightDirection[i];
  sh.flatGradient = c.flatGradient;
  sh.gradientOpacityLow = c.gradientOpacityLow;
  sh.gradientOpacityWidth = c.gradientOpacityWidth;
  tf.opacity.assign(static_cast<std::size_t>(c.opacityPoints), glm::dvec4(0.0));
  for (std::size_t i = 0; i < tf.opacity.size(); ++i) tf.opacity[i] = glm::dvec4(c.opacity[i][0], c.opacity[i][1], 0, 0);
  tf.colour.assign(static_cast<std::size_t>(c.colourPoints), glm::dvec4(0.0));
  for (std::size_t i = 0; i < tf.colour.size(); ++i)
    tf.colour[i] = glm::dvec4(c.colour[i][0], c.colour[i][1], c.colour[i][2], c.colour[i][3]);
}

pp::CompositeMode liveMode(const comm::ControlState& c) { return static_cast<pp::CompositeMode>(c.liveMode); }

Camera controlCamera(const comm::ControlState& c, const RenderSettings& base, const Grid& grid) {
  RenderSettings r = base;
  gp::ShadeSettings sh;
  TransferFunctionSettings tf;
  applyControlState(c, r, sh, tf);
  Camera cam = makeCamera(r, grid);
  if (c.orbitValid) cam = cam.orbited(Vec3(c.orbitAxis[0], c.orbitAxis[1], c.orbitAxis[2]), c.orbitDeg);
  return cam;
}

std::uint32_t controlChanges(const comm::ControlState& a, const comm::ControlState& b) {
  std::uint32_t ch = 0;
  auto differs = [](const auto& x, const auto& y) { return std::memcmp(&x, &y, sizeof x) != 0; };
  if (a.projection != b.projection || differs(a.fovDeg, b.fovDeg) || differs(a.azimuthDeg, b.azimuthDeg) ||
      differs(a.elevationDeg, b.elevationDeg) || differs(a.distance, b.distance) || a.orbitValid != b.orbitValid ||
      differs(a.orbitAxis, b.orbitAxis) || differs(a.orbitDeg, b.orbitDeg) ||
      differs(a.stepScale, b.stepScale) || a.pixelStride != b.pixelStride || differs(a.panMm, b.panMm))
    ch |= comm::ControlMsg::kView;
  if (a.shadeMode != b.shadeMode || a.light != b.light || a.gradientOpacity != b.gradientOpacity ||
      differs(a.ambient, b.ambient) || differs(a.diffuse, b.diffuse) || differs(a.specular, b.specular) ||
      differs(a.shininess, b.shininess) || differs(a.lightDirection, b.lightDirection) ||
      differs(a.flatGradient, b.flatGradient) || differs(a.gradientOpacityLow, b.gradientOpacityLow) ||
      differs(a.gradientOpacityWidth, b.gradientOpacityWidth))
    ch |= comm::ControlMsg::kShading;
  if (a.opacityPoints != b.opacityPoints || a.colourPoints != b.colourPoints || differs(a.opacity, b.opacity) ||
      differs(a.colour, b.colour))
    ch |= comm::ControlMsg::kTransfer;
  if (a.liveMode != b.liveMode || differs(a.valueWindow, b.valueWindow)) ch |= comm::ControlMsg::kMode;
  // Between "over" and the grey-value modes the GPs shade and sample anew.
  if (compositesGreyValues(liveMode(a)) != compositesGreyValues(liveMode(b))) ch |= comm::ControlMsg::kShading;
  return ch;
}

}  // namespace pp5::parallel
