// Windowed reconstruction (the `slab` partitioning): a reconstructor limited to
// a window of the grid, fed only the frames that can reach it (the others by
// advance(), their pixels given back by restorePrevious() when the next
// frame's fill-in needs them), must hold the serial pipeline's bits inside
// the window after every frame.
//
// The oracle: an unrestricted reconstructor over every frame. A frame goes to
// insert() either when it changed some voxel of the windowed reconstructor's
// reach() (its output or weight, compared bit for bit before and after the
// frame: the tightest choice, so frames that touch the reach without changing
// it are advanced too), or, as a host decides, when the reference's dirty
// region of the frame (its support slabs) overlaps the reach.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <ostream>
#include <random>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "core/error.hpp"
#include "core/transform.hpp"
#include "reconstruction/reconstruction.hpp"

namespace pp5::gp {
namespace {

constexpr int kW = 24, kH = 18;          // frame size, pixels
constexpr double kSx = 0.8, kSy = 0.9;   // pixel spacing, mm
constexpr std::int64_t kN = 32;          // grid: kN^3 voxels of 1 mm

Grid testGrid() {
  Grid g;
  g.dims = Index3(kN);
  g.spacing = Vec3(1.0);
  g.origin = Vec3(-(static_cast<double>(kN) - 1.0) * 0.5);
  return g;
}

glm::dmat3 rot(const Vec3& axis, double radians) { return glm::dmat3(rotationAxisAngle(axis, radians)); }

// The pose that puts the image's centre at `centre`, with orientation r
// (columns: image x, image y, normal).
Mat4 centredPose(const Vec3& centre, const glm::dmat3& r) {
  const Vec3 origin = centre - r[0] * (kSx * (kW - 1) * 0.5) - r[1] * (kSy * (kH - 1) * 0.5);
  Mat4 m(1.0);
  m[0] = Vec4(r[0] * kSx, 0.0);
  m[1] = Vec4(r[1] * kSy, 0.0);
  m[2] = Vec4(r[2], 0.0);
  m[3] = Vec4(origin, 1.0);
  return m;
}

struct Sweep {
  std::vector<Frame> frames;
  std::vector<Mat4> poses;
  std::vector<double> times;
};

// A freehand-like sweep across x (the slices face x): small rotations every
// frame, a tilt in the middle of the first pass, a jump back (farther than
// fill_in_max_gap_mm) after a pause, a second pass, a reversal, and a jittery
// end that steps back and forth along x and sideways along y (so that a
// motion-vector cell on a window's edge sees slices of both directions in
// turn, some reaching only its part outside the window). Random pixels, about
// one in six of them 0.
Sweep makeSweep(unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> value(1, 255);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  std::vector<double> xs;
  for (int n = 0; n < 9; ++n) xs.push_back(-12.0 + 2.6 * n);  // first pass, forwards
  for (int n = 0; n < 6; ++n) xs.push_back(-6.0 + 2.2 * n);   // after the jump
  for (int n = 0; n < 8; ++n) xs.push_back(3.0 - 2.4 * n);    // reversed
  const std::size_t jitter = xs.size();
  for (int n = 0; n < 12; ++n) xs.push_back(-12.0 + 0.8 * n + (n % 2 ? -1.2 : 0.0));  // +2.0, -1.2, ...
  // The slice's own axes: image x along grid y, image y along grid z, normal along x.
  const glm::dmat3 base(Vec3(0, 1, 0), Vec3(0, 0, 1), Vec3(1, 0, 0));
  Sweep s;
  double t = 0.0;
  for (std::size_t n = 0; n < xs.size(); ++n) {
    const double k = static_cast<double>(n);
    const double yaw = 0.05 * std::sin(0.9 * k);                     // about grid z
    const double tilt = (n >= 4 && n <= 6) ? 0.12 * (k - 3.0) : 0.0;  // about grid y, up to 0.36 rad
    const glm::dmat3 r = rot(Vec3(0, 0, 1), yaw) * rot(Vec3(0, 1, 0), tilt) * base;
    const double side = n >= jitter ? (n % 2 ? 2.0 : -1.0) : 1.5 * std::sin(0.3 * k);
    const Vec3 centre(xs[n], side, -1.0 + 0.05 * k);
    s.poses.push_back(centredPose(centre, r));
    t += n == 9 ? 1.0 : 0.05 + 0.02 * static_cast<double>(n % 3);  // a pause before the jump
    s.times.push_back(t);
    Frame f;
    f.allocate(kW, kH, PixelType::U8);
    f.index = n;
    for (auto& p : f.pixels) p = u01(rng) < 1.0 / 6.0 ? 0 : static_cast<std::uint8_t>(value(rng));
    s.frames.push_back(std::move(f));
  }
  return s;
}

// The kernel of test_splat_tent (he = 1.5 mm, so frames 2-3 mm apart get
// fill-in slices), a gap limit the jump exceeds, and decay fast enough to
// matter between frames.
ReconSettings tentSettings(const std::string& replacement) {
  ReconSettings s;
  s.threads = 1;
  s.tent.kernelLateralMm = 1.0;
  s.tent.kernelAxialMm = 0.75;
  s.tent.kernelElevationMm = 1.5;
  s.tent.fillIn = true;
  s.tent.fillInMaxGapMm = 8.0;
  s.tent.replacement = pp5::enumFromName<pp5::gp::Replacement>(replacement);
  s.tent.motionVectorBrick = 5;  // does not divide the grid: the last cells are partial
  s.tent.decayTauS = 0.3;
  return s;
}

std::uint32_t bitsAt(const Volume& v, std::size_t i) {
  std::uint32_t x;
  std::memcpy(&x, v.bytes.data() + 4 * i, sizeof x);
  return x;
}

// Whether two F32 volumes hold the same bits inside `box`; the first voxel
// that differs into `where`.
bool sameInside(const Volume& a, const Volume& b, const Box3& box, std::string* where = nullptr) {
  const Grid& g = a.grid;
  for (std::int64_t k = box.lo.z; k < box.hi.z; ++k)
    for (std::int64_t j = box.lo.y; j < box.hi.y; ++j)
      for (std::int64_t i = box.lo.x; i < box.hi.x; ++i) {
        const std::size_t v = g.linear(i, j, k);
        if (bitsAt(a, v) != bitsAt(b, v)) {
          if (where) {
            float fa, fb;
            std::memcpy(&fa, a.bytes.data() + 4 * v, 4);
            std::memcpy(&fb, b.bytes.data() + 4 * v, 4);
            *where = fmt::format("voxel ({}, {}, {}): {} vs {}", i, j, k, fa, fb);
          }
          return false;
        }
      }
  return true;
}

std::string str(const Box3& b) {
  return fmt::format("[{} {} {}]..[{} {} {}]", b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z);
}

// The unrestricted run: output and weights after every frame (index 0 = before the first).
struct Reference {
  std::vector<Volume> out, wts;
  std::vector<DirtyRegion> dirty;  // per frame
};

Reference referenceRun(const Grid& g, const ReconSettings& s, const Sweep& sw) {
  auto rec = makeReconstructor(g, s);
  Reference ref;
  ref.out.push_back(rec->output());
  ref.wts.push_back(rec->weights());
  for (std::size_t n = 0; n < sw.frames.size(); ++n) {
    ref.dirty.push_back(rec->insert(sw.frames[n], sw.poses[n], sw.times[n]).dirty);
    ref.out.push_back(rec->output());
    ref.wts.push_back(rec->weights());
  }
  return ref;
}

enum class Oracle { Diff, Dirty };

bool overlaps(const DirtyRegion& d, const Box3& box) {
  for (const Box3& b : d.boxes())
    if (!b.intersect(box).empty()) return true;
  return false;
}

struct WindowStats {
  int inserted = 0, advanced = 0, restored = 0, fillInAfterRestore = 0;
};

// Feeds the sweep to a reconstructor limited to `window` as a host would, and
// checks it against the reference after every frame. Returns the reconstructor.
std::unique_ptr<Reconstructor> windowedRun(const Grid& g, const ReconSettings& s, const Sweep& sw,
                                           const Reference& ref, const Box3& window, WindowStats& st,
                                           Oracle oracle = Oracle::Diff) {
  auto rec = makeReconstructor(g, s);
  rec->setWindow(window);
  const Box3 clipped = window.intersect({Index3(0), g.dims});
  EXPECT_EQ(rec->window(), clipped.empty() ? Box3{} : clipped);
  EXPECT_EQ(rec->reach(), reconstructionReach(g, s, window));
  const Box3 reach = rec->reach();
  bool prevAdvanced = false;
  for (std::size_t n = 0; n < sw.frames.size(); ++n) {
    SCOPED_TRACE(fmt::format("window {}, frame {}, oracle {}", str(window), n, oracle == Oracle::Diff ? "diff" : "dirty"));
    const bool changed = !sameInside(ref.out[n], ref.out[n + 1], reach) || !sameInside(ref.wts[n], ref.wts[n + 1], reach);
    const bool needed = oracle == Oracle::Diff ? changed : overlaps(ref.dirty[n], reach);
    EXPECT_TRUE(needed || !changed);  // the dirty region is conservative
    InsertResult res;
    if (!needed) {
      res = rec->advance(sw.frames[n].width, sw.frames[n].height, sw.poses[n], sw.times[n]);
      EXPECT_TRUE(res.dirty.empty());
      EXPECT_EQ(res.fillInSlices, 0);
      ++st.advanced;
      prevAdvanced = true;
    } else {
      if (prevAdvanced) {
        rec->restorePrevious(sw.frames[n - 1]);
        ++st.restored;
      }
      res = rec->insert(sw.frames[n], sw.poses[n], sw.times[n]);
      if (prevAdvanced && res.fillInSlices > 0) ++st.fillInAfterRestore;
      ++st.inserted;
      prevAdvanced = false;
    }
    std::string where;
    EXPECT_TRUE(sameInside(rec->output(), ref.out[n + 1], rec->window(), &where)) << "output, " << where;
    EXPECT_TRUE(sameInside(rec->weights(), ref.wts[n + 1], rec->window(), &where)) << "weights, " << where;
    // The dirty region, and the changed runs where the method reports them,
    // cover every voxel of the window whose output changed.
    const Box3 w = rec->window();
    std::vector<std::uint8_t> inRuns(g.voxelCount(), 0);
    for (const RowRun& r : res.changedRuns)
      for (std::int64_t i = r.i0; i <= r.i1; ++i) inRuns[g.linear(i, r.j, r.k)] = 1;
    int uncovered = 0, outsideRuns = 0;
    for (std::int64_t k = w.lo.z; k < w.hi.z; ++k)
      for (std::int64_t j = w.lo.y; j < w.hi.y; ++j)
        for (std::int64_t i = w.lo.x; i < w.hi.x; ++i) {
          const std::size_t v = g.linear(i, j, k);
          if (bitsAt(ref.out[n], v) == bitsAt(ref.out[n + 1], v)) continue;
          if (!res.dirty.containsVoxel(i, j, k)) ++uncovered;
          if (rec->reportsChangedRuns() && !inRuns[v]) ++outsideRuns;
        }
    EXPECT_EQ(uncovered, 0);
    EXPECT_EQ(outsideRuns, 0);
    if (::testing::Test::HasFailure()) break;  // one frame's report is enough
  }
  return rec;
}

// Random boxes, aligned and not, one on the grid's edge, thin ones, one
// reaching out of the grid, and the whole grid.
std::vector<Box3> testWindows(unsigned seed) {
  std::vector<Box3> w = {
      {Index3(8, 8, 8), Index3(24, 24, 16)},     // aligned to 8
      {Index3(20, 0, 5), Index3(32, 13, 32)},    // on the grid's edge
      {Index3(3, 2, 15), Index3(29, 30, 16)},    // one voxel thick (z)
      {Index3(17, 4, 6), Index3(18, 28, 25)},    // one voxel thick (x, across the sweep)
      {Index3(-5, 25, 10), Index3(6, 40, 20)},   // partly outside the grid
      {Index3(0), Index3(kN)},                   // the whole grid
  };
  std::mt19937 rng(seed);
  std::uniform_int_distribution<std::int64_t> lo(0, kN - 2), size(1, 14);
  for (int r = 0; r < 4; ++r) {
    Box3 b;
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = lo(rng);
      b.hi[a] = std::min<std::int64_t>(kN, b.lo[a] + size(rng));
    }
    w.push_back(b);
  }
  return w;
}

struct TentCase {
  const char* name;
  const char* replacement;
  bool clip;
  bool reject;  // reject the zero pixels (the slices then have masks)
};
void PrintTo(const TentCase& c, std::ostream* os) { *os << c.name; }

class TentWindow : public ::testing::TestWithParam<TentCase> {};

TEST_P(TentWindow, WindowEqualsTheUnrestrictedReconstructionAfterEveryFrame) {
  const TentCase c = GetParam();
  const Grid g = testGrid();
  ReconSettings s = tentSettings(c.replacement);
  if (c.clip) {
    s.clipOrigin = {3, 2};
    s.clipSize = {17, 13};
  }
  if (c.reject) s.pixelRejectionThreshold = 0.5;
  const Sweep sw = makeSweep(7);
  const Reference ref = referenceRun(g, s, sw);
  WindowStats st;
  for (const Box3& w : testWindows(11))
    for (const Oracle o : {Oracle::Diff, Oracle::Dirty}) {
      windowedRun(g, s, sw, ref, w, st, o);
      if (HasFailure()) return;
    }
  // Every path was taken: frames skipped, pixels given back, fill-in from them.
  EXPECT_GT(st.advanced, 10);
  EXPECT_GT(st.restored, 2);
  EXPECT_GT(st.fillInAfterRestore, 0);
  EXPECT_GT(st.inserted, 10);
}

INSTANTIATE_TEST_SUITE_P(Replacements, TentWindow,
                         ::testing::Values(TentCase{"accumulate", "accumulate", false, false},
                                           TentCase{"accumulate_clip_reject", "accumulate", true, true},
                                           TentCase{"motion_vector", "motion_vector", false, false},
                                           TentCase{"motion_vector_clip", "motion_vector", true, true},
                                           TentCase{"decay", "decay", false, true},
                                           TentCase{"decay_clip", "decay", true, false}),
                         [](const auto& info) { return std::string(info.param.name); });

// The sweep really reverses and rebases: without the rounding of the window
// to whole cells, a cell straddling its edge would decide differently. The
// reach is rounded out to the cells, aligned to the grid and clipped to it.
TEST(TentWindow, MotionVectorReachIsWholeCells) {
  const Grid g = testGrid();
  const ReconSettings s = tentSettings("motion_vector");  // cells of 5
  EXPECT_EQ(reconstructionReach(g, s, {Index3(3, 5, 29), Index3(9, 6, 31)}),
            (Box3{Index3(0, 5, 25), Index3(10, 10, kN)}));
  EXPECT_EQ(reconstructionReach(g, tentSettings("accumulate"), {Index3(3, 5, 29), Index3(9, 6, 40)}),
            (Box3{Index3(3, 5, 29), Index3(9, 6, kN)}));
  EXPECT_TRUE(reconstructionReach(g, s, {Index3(40), Index3(50)}).empty());
  auto rec = makeReconstructor(g, s);
  EXPECT_EQ(rec->window(), (Box3{Index3(0), g.dims}));
  EXPECT_EQ(rec->reach(), (Box3{Index3(0), g.dims}));
}

// A window the sweep never reaches: every frame advanced, nothing written in
// it, and the reference agrees that nothing was.
TEST(TentWindow, AdvanceOnlyLeavesAFarWindowUntouched) {
  const Grid g = testGrid();
  for (const char* repl : {"accumulate", "motion_vector", "decay"}) {
    SCOPED_TRACE(repl);
    const ReconSettings s = tentSettings(repl);
    const Sweep sw = makeSweep(3);
    const Box3 far{Index3(0, 30, 30), Index3(kN)};  // whole cells of 5, so the reach is the window
    auto ref = makeReconstructor(g, s);
    auto rec = makeReconstructor(g, s);
    rec->setWindow(far);
    for (std::size_t n = 0; n < sw.frames.size(); ++n) {
      ref->insert(sw.frames[n], sw.poses[n], sw.times[n]);
      const InsertResult r = rec->advance(kW, kH, sw.poses[n], sw.times[n]);
      EXPECT_TRUE(r.dirty.empty());
      EXPECT_EQ(r.pixelsInserted, 0u);
    }
    const Volume zero = [&] {
      Volume z;
      z.allocate(g, ScalarType::F32);
      return z;
    }();
    EXPECT_TRUE(sameInside(ref->weights(), zero, rec->reach()));  // the setup: the sweep misses the window
    EXPECT_TRUE(sameInside(rec->output(), zero, Box3{Index3(0), g.dims}));
    EXPECT_TRUE(sameInside(rec->weights(), zero, Box3{Index3(0), g.dims}));
    // The stream state kept up: a frame inserted now equals the reference's.
    Frame f = sw.frames.back();
    const Mat4 pose = centredPose(Vec3(-13.0, 9.0, 8.0), glm::dmat3(Vec3(0, 1, 0), Vec3(0, 0, 1), Vec3(1, 0, 0)));
    const double t = sw.times.back() + 0.1;
    rec->restorePrevious(sw.frames.back());
    const InsertResult a = ref->insert(f, pose, t), b = rec->insert(f, pose, t);
    EXPECT_EQ(a.fillInSlices, b.fillInSlices);
    EXPECT_TRUE(sameInside(rec->output(), ref->output(), rec->window()));
    EXPECT_TRUE(sameInside(rec->weights(), ref->weights(), rec->window()));
  }
}

// The threads split the clipped rows: 1 and 2 threads give the same bits
// everywhere (outside the window too, as both do the same work).
TEST(TentWindow, ThreadCountsAgree) {
  const Grid g = testGrid();
  const Sweep sw = makeSweep(5);
  for (const char* repl : {"accumulate", "motion_vector", "decay"}) {
    SCOPED_TRACE(repl);
    ReconSettings s = tentSettings(repl);
    const Reference ref = referenceRun(g, s, sw);
    WindowStats st;
    const Box3 w{Index3(2, 3, 4), Index3(27, 30, 21)};
    auto one = windowedRun(g, s, sw, ref, w, st);
    s.threads = 2;
    auto two = windowedRun(g, s, sw, ref, w, st);
    const Box3 all{Index3(0), g.dims};
    EXPECT_TRUE(sameInside(one->output(), two->output(), all));
    EXPECT_TRUE(sameInside(one->weights(), two->weights(), all));
  }
}

// Without restorePrevious() the previous frame's pixels are unknown: no
// fill-in. With it, the same fill-in as unrestricted.
TEST(TentWindow, FillInNeedsThePreviousPixels) {
  const Grid g = testGrid();
  const ReconSettings s = tentSettings("accumulate");
  const Sweep sw = makeSweep(9);
  auto ref = makeReconstructor(g, s);
  ref->insert(sw.frames[0], sw.poses[0], sw.times[0]);
  const int expected = ref->insert(sw.frames[1], sw.poses[1], sw.times[1]).fillInSlices;
  ASSERT_GT(expected, 0);
  for (const bool restore : {false, true}) {
    auto rec = makeReconstructor(g, s);
    rec->setWindow({Index3(0), Index3(kN, kN, 16)});
    rec->advance(kW, kH, sw.poses[0], sw.times[0]);
    if (restore) rec->restorePrevious(sw.frames[0]);
    EXPECT_EQ(rec->insert(sw.frames[1], sw.poses[1], sw.times[1]).fillInSlices, restore ? expected : 0);
  }
}

// The dirty region of a windowed insert keeps to the bricks that overlap the window.
TEST(TentWindow, DirtyRegionStaysNearTheWindow) {
  const Grid g = testGrid();
  const ReconSettings s = tentSettings("accumulate");
  const Sweep sw = makeSweep(1);
  auto full = makeReconstructor(g, s);
  auto rec = makeReconstructor(g, s);
  const Box3 w{Index3(0, 0, 0), Index3(kN, 12, 12)};
  rec->setWindow(w);
  const InsertResult a = full->insert(sw.frames[0], sw.poses[0], sw.times[0]);
  const InsertResult b = rec->insert(sw.frames[0], sw.poses[0], sw.times[0]);
  EXPECT_FALSE(b.dirty.empty());
  EXPECT_LT(b.dirty.bricks().size(), a.dirty.bricks().size());
  for (const Box3& box : b.dirty.boxes()) EXPECT_FALSE(box.intersect(w).empty()) << str(box);
  EXPECT_EQ(a.pixelsInserted, b.pixelsInserted);
}

// The checks of advance() are insert()'s; restorePrevious() and setWindow()
// refuse what the contract does not allow; a refused advance changes nothing.
TEST(TentWindow, InputsAreCheckedAsInsertChecksThem) {
  const Grid g = testGrid();
  for (const char* method : {"tent", "nearest"}) {
    SCOPED_TRACE(method);
    ReconSettings s = tentSettings("accumulate");
    s.method = pp5::enumFromName<pp5::gp::Method>(method);
    const Sweep sw = makeSweep(2);
    auto rec = makeReconstructor(g, s);
    rec->setWindow({Index3(4), Index3(20)});
    auto message = [](const auto& fn) {
      try {
        fn();
      } catch (const InputError& e) {
        const std::string m = e.what();
        return m.substr(m.find(": ") + 2);  // less the frame's name
      }
      return std::string("no error");
    };
    Mat4 bad = sw.poses[0];
    bad[3][3] = std::nan("");
    EXPECT_EQ(message([&] { rec->advance(kW, kH, bad, 0.0); }), message([&] { rec->insert(sw.frames[0], bad, 0.0); }));
    EXPECT_EQ(message([&] { rec->advance(0, kH, sw.poses[0], 0.0); }), [&] {
      Frame e;
      e.height = kH;
      return message([&] { rec->insert(e, sw.poses[0], 0.0); });
    }());
    {
      Frame shortFrame = sw.frames[0];
      shortFrame.pixels.pop_back();
      rec->advance(kW, kH, sw.poses[0], sw.times[0]);
      EXPECT_THROW(rec->restorePrevious(shortFrame), InputError);
    }
    if (std::string(method) == "tent") {
      Mat4 proj = sw.poses[0];
      proj[0][3] = 0.5;
      EXPECT_EQ(message([&] { rec->advance(kW, kH, proj, 0.0); }),
                message([&] { rec->insert(sw.frames[0], proj, 0.0); }));
      EXPECT_NE(message([&] { rec->advance(kW, kH, proj, 0.0); }).find("not affine"), std::string::npos);
      const double inf = std::numeric_limits<double>::infinity();
      EXPECT_EQ(message([&] { rec->advance(kW, kH, sw.poses[0], inf); }),
                message([&] { rec->insert(sw.frames[0], sw.poses[0], inf); }));
      EXPECT_NE(message([&] { rec->advance(kW, kH, sw.poses[0], inf); }).find("timestamp"), std::string::npos);
    }
    // restorePrevious: only right after advance(), and only with the advanced frame's size.
    rec->insert(sw.frames[0], sw.poses[0], sw.times[0]);
    EXPECT_THROW(rec->restorePrevious(sw.frames[0]), InvariantError);  // the last call was not an advance
    rec->advance(kW, kH, sw.poses[0], sw.times[0]);
    Frame other;
    other.allocate(kW + 1, kH, PixelType::U8);
    EXPECT_THROW(rec->restorePrevious(other), InvariantError);
    EXPECT_NO_THROW(rec->restorePrevious(sw.frames[0]));
    EXPECT_THROW(rec->restorePrevious(sw.frames[0]), InvariantError);  // once
    EXPECT_THROW(rec->setWindow({Index3(0), Index3(8)}), InvariantError);  // after the first frame
  }
  // A refused advance changes nothing: the rest of the stream still matches.
  const ReconSettings s = tentSettings("motion_vector");
  const Sweep sw = makeSweep(4);
  auto ref = makeReconstructor(g, s);
  auto rec = makeReconstructor(g, s);
  rec->setWindow({Index3(0), Index3(kN, kN, 14)});
  for (std::size_t n = 0; n < sw.frames.size(); ++n) {
    ref->insert(sw.frames[n], sw.poses[n], sw.times[n]);
    EXPECT_THROW(rec->advance(kW, kH, sw.poses[n], std::nan("")), InputError);
    rec->insert(sw.frames[n], sw.poses[n], sw.times[n]);
  }
  EXPECT_TRUE(sameInside(rec->output(), ref->output(), rec->window()));
  EXPECT_TRUE(sameInside(rec->weights(), ref->weights(), rec->window()));
}

// The pixel methods ignore the window and splat every frame they get in full;
// fed as a host feeds them, they equal the unrestricted reconstruction inside
// the window (hole filling included, with the reach grown by its kernel).
struct PixelCase {
  const char* name;
  const char* method;
  const char* compounding;
  bool fillHoles;
};
void PrintTo(const PixelCase& c, std::ostream* os) { *os << c.name; }

class PixelWindow : public ::testing::TestWithParam<PixelCase> {};

TEST_P(PixelWindow, WindowEqualsTheUnrestrictedReconstruction) {
  const PixelCase c = GetParam();
  const Grid g = testGrid();
  ReconSettings s;
  s.threads = 1;
  s.method = pp5::enumFromName<pp5::gp::Method>(c.method);
  s.pixel.compounding = pp5::enumFromName<pp5::gp::Compounding>(c.compounding);
  s.pixel.fillHoles = c.fillHoles;
  s.pixel.fillHolesIncremental = c.fillHoles;
  const Sweep sw = makeSweep(13);
  const Reference ref = referenceRun(g, s, sw);
  WindowStats st;
  const std::vector<Box3> windows = testWindows(17);
  for (std::size_t i = 0; i < windows.size(); ++i)
    for (const Oracle o : {Oracle::Diff, Oracle::Dirty}) {
      // Incremental hole filling is slow: half the windows, one oracle each.
      if (c.fillHoles && (i % 2 == 1 || (o == Oracle::Dirty) != (i % 4 == 0))) continue;
      windowedRun(g, s, sw, ref, windows[i], st, o);
      if (HasFailure()) return;
    }
  EXPECT_GT(st.advanced, 5);
  EXPECT_GT(st.inserted, 5);
}

INSTANTIATE_TEST_SUITE_P(Methods, PixelWindow,
                         ::testing::Values(PixelCase{"nearest_mean", "nearest", "mean", false},
                                           PixelCase{"trilinear_maximum", "trilinear", "maximum", false},
                                           PixelCase{"trilinear_mean_holes", "trilinear", "mean", true}),
                         [](const auto& info) { return std::string(info.param.name); });

TEST(PixelWindow, HoleFillingGrowsTheReach) {
  const Grid g = testGrid();
  ReconSettings s;
  s.method = pp5::gp::Method::Nearest;
  const Box3 w{Index3(10), Index3(12)};
  EXPECT_EQ(reconstructionReach(g, s, w), w);
  s.pixel.fillHoles = true;  // the default STICK kernel of length 9
  const Box3 r = reconstructionReach(g, s, w);
  EXPECT_LT(r.lo.x, w.lo.x);
  EXPECT_GT(r.hi.x, w.hi.x);
  EXPECT_EQ(r.hi - w.hi, w.lo - r.lo);
}

}  // namespace
}  // namespace pp5::gp
