#pragma once
// PLUS-compatible reconstruction: pixel nearest neighbour and trilinear
// splatting with MEAN / LATEST / MAXIMUM compounding, clip rectangle, fan and
// pixel rejection, in PLUS's fixed-point arithmetic or in exact float.
//
// Pixel selection (both arithmetics): PLUS's clip rectangle (end included)
// and fan, as runs per row (reconstruction/fan_mask.hpp); pixels darker than
// pixel_rejection_threshold are skipped. SkipInterval is the caller's.
//
// arithmetic = "plus" (docs/notes/plus-reconstruction.md): PLUS's FULL
// optimisation exactly - 14-bit fixed-point positions and trilinear weights,
// an 8-bit value and a 16-bit accumulator per voxel (256 = one pixel), the
// truncating running mean of nearest neighbour and its saturated filter, the
// rounding running mean of trilinear, LATEST / MAXIMUM replacing the
// accumulator, a trilinear pixel dropped unless all eight corners are inside.
// Reproduces PLUS's four regression volumes bit for bit. Frames must be 8-bit.
//  - output() is PLUS's 8-bit volume as grey levels. Like PLUS it keeps the
//    value of a trilinear MEAN voxel whose accumulator rounded to 0 (total
//    weight below 1/512), although covered() is false there.
//  - weights() is the accumulator / 256.
//
// arithmetic = "float": PLUS's weaknesses fixed.
//  - Positions in double; a pixel's voxel is floor(position + 1/2) (nearest)
//    and its lower corner floor(position) (trilinear), decided where the row
//    crosses voxel boundaries (see splat_pixel.cpp).
//  - MEAN: float sums of weight x value and of weight, no saturation (8-bit
//    values with unit weights stay exact up to 65793 hits), divided once
//    for output(): output() holds the exact weighted mean, not rounded.
//  - Trilinear weights (1-f)(1-g)(1-h) ... in float; at the volume border the
//    corners inside the grid keep their weights.
//  - LATEST: a voxel takes the value of the last pixel that reaches it;
//    MAXIMUM: the largest such value. With trilinear a pixel reaches a corner
//    only where its weight is at least 1/8 (PLUS's rule). weights() is the
//    sum of the weights of those pixels (nearest: their count).
//  - 8- and 16-bit frames.
//
// Any thread count gives the same bits (slabs of the grid owned by one thread
// each, pixels visited in row-major order by every thread). insert() updates
// output() inside the returned dirty region, hole filling included when it is
// incremental; see reconstruction/hole_fill.hpp for the hole filling.
#include <memory>

#include "reconstruction/reconstruction.hpp"

namespace pp5::gp {

std::uint64_t pixelBytesPerVoxel(const ReconSettings& s);
std::unique_ptr<Reconstructor> makePixelReconstructor(const Grid& g, const ReconSettings& s);

}  // namespace pp5::gp
