#pragma once
// Which samples a changed voxel affects: the sample at voxel position p
// (float, VoxelRay::at) reads the 8 voxels of the cell floor(p) (clamped to the
// grid's last cell), so a voxel v changes the samples with floor(p) in [v - 1,
// v] along each axis, the samples within one voxel of it. The grow rule for a
// box of changed voxels [lo, hi) is therefore: the sampling points with p in
// [lo - 1, hi] (voxel units), clipped to the sampling box [0, dims - 1], and
// widened by kStencilSlackVoxels for the float rounding of p. stencilBoxes()
// applies it; pass it the voxels whose *shade* changed (e.g.
// shadingBoxes(dirty), which already adds the gradient's reach). The D-buffer
// of those boxes then covers every sample that can have changed, plus the
// few within the slack.
#include <optional>
#include <span>
#include <vector>

#include "core/grid.hpp"
#include "core/sample_lattice.hpp"
#include "rendering/dbuffer.hpp"
#include "reconstruction/dirty_region.hpp"

namespace pp5::gp {

// Voxel units added around each stencil box: far more than the float error of
// a sample position (a few 1e-5 voxel in a 1024^3 grid), so the D-buffer
// never misses a sample whose stencil touches a changed voxel.
inline constexpr double kStencilSlackVoxels = 1.0 / 256.0;

// The world boxes (sampling-box clipped) that hold every lattice sample whose
// trilinear stencil touches a voxel of `changed` grown by `extraVoxels`.
std::vector<WorldBox> stencilBoxes(const Grid& grid, std::span<const Box3> changed, int extraVoxels = 0);
// The same for the bricks of `changed`: runs of bricks are merged into larger
// boxes first, so the D-buffer scan-converts a few boxes rather than many.
std::vector<WorldBox> stencilBoxes(const DirtyRegion& changed, int extraVoxels = 0);

// The voxel cell (its lowest corner) whose 8 voxels sample k of `pixel` reads:
// the cell SamplerOptions::ownedCells tests, by the sampler's arithmetic.
Index3 stencilCell(const SampleLattice& lattice, std::uint32_t pixel, std::uint32_t k);

// The pixels whose rays can take a sample that reads a voxel of `b` (the
// grow rule above) under `camera`: an inclusive rectangle of pixel indices,
// with one pixel of margin for rounding and not clipped to the image.
// nullopt when the box reaches behind the eye (then any pixel may).
struct PixelBounds {
  double x0 = 0, y0 = 0, x1 = 0, y1 = 0;
};
std::optional<PixelBounds> stencilFootprint(const Grid& grid, const Box3& b, const Camera& camera);

}  // namespace pp5::gp
