#pragma once
// Which pixels of a frame the pixel methods insert: PLUS's clip rectangle and
// fan (docs/notes/plus-reconstruction.md, section 3.7), as runs of columns per
// row. The mask does not depend on the pose, so it is computed once per frame
// size. Both arithmetics use the same mask: it is geometry, not arithmetic,
// and PLUS's 2^-16 tolerance in its row limits is what makes a 45-degree edge
// (tan = 0.9999999999999999) land on whole pixels as intended.
#include <vector>

#include "reconstruction/reconstruction.hpp"

namespace pp5::gp {

// Columns x0..x1 (inclusive) of row y.
struct PixelRun {
  int y = 0;
  int x0 = 0;
  int x1 = -1;
  bool operator==(const PixelRun&) const = default;
};

// Rows ascending, runs left to right within a row (at most two per row: the
// fan's inner radius can cut one out of the middle).
//  - Clip rectangle (both sizes > 0): columns clipOrigin.x .. clipOrigin.x +
//    clipSize.x and rows likewise, end included as in PLUS (one more than the
//    size), clamped to the frame.
//  - Fan (on when either angle's tangent is non-zero): a row y (pixels below
//    the fan origin) keeps the columns inside both angle lines and the outer
//    radius, minus those inside the inner radius, each edge one pixel inwards.
std::vector<PixelRun> pixelRuns(int width, int height, const ReconSettings& s);

}  // namespace pp5::gp
