// The global sample lattice, the D-buffer and the ray sampler (issue 4).
#include <gtest/gtest.h>

#include <bit>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include "core/camera.hpp"
#include "core/grid.hpp"
#include "core/render_settings.hpp"
#include "rendering/dbuffer.hpp"
#include "reconstruction/dirty_region.hpp"
#include "rendering/ray_sampler.hpp"
#include "core/sample_lattice.hpp"
#include "rendering/shade_buffer.hpp"

#include "geometry_test_util.hpp"

namespace {

using pp5::Camera;
using pp5::Grid;
using pp5::Index3;
using pp5::Projection;
using pp5::Ray;
using pp5::RaySample;
using pp5::RenderSettings;
using pp5::Vec3;
using pp5::gp::Box3;
using pp5::gp::DBuffer;
using pp5::SampleLattice;
using pp5::gp::ShadeBuffer;
using pp5::gp::ShadeVoxel;
using pp5::gp::WorldBox;

Grid testGrid() {
  Grid g;
  g.origin = Vec3(-19.0, -14.0, -17.5);
  g.spacing = Vec3(1.0, 0.9, 1.1);
  g.dims = Index3(40, 33, 31);
  return g;
}

using pp5::test::gridCentre;
using pp5::test::randomUnit;

// A random view of the grid (the shared draw's defaults). eyeInside: the eye in the grid's box.
Camera randomCamera(std::mt19937& rng, const Grid& g, Projection proj, bool eyeInside, int w = 72, int h = 60) {
  return pp5::test::randomCamera(rng, g, proj, eyeInside, w, h);
}

// Brute force: the sorted, merged union of [max(enter, 0), exit] over boxes.
using Intervals = std::vector<std::pair<double, double>>;
Intervals bruteUnion(const Ray& r, const std::vector<WorldBox>& boxes, double grow) {
  Intervals v;
  for (const auto& b : boxes) {
    double e0, e1;
    const Vec3 lo = b.lo - Vec3(grow), hi = b.hi + Vec3(grow);
    if (hi.x < lo.x || hi.y < lo.y || hi.z < lo.z) continue;
    if (!pp5::intersectBox(r, lo, hi, e0, e1)) continue;
    e0 = std::max(e0, 0.0);
    if (e1 >= e0) v.emplace_back(e0, e1);
  }
  std::sort(v.begin(), v.end());
  Intervals m;
  for (const auto& i : v) {
    if (!m.empty() && i.first <= m.back().second) m.back().second = std::max(m.back().second, i.second);
    else m.push_back(i);
  }
  return m;
}

// Compares one pixel's D-buffer spans with the brute-force union for the
// boxes shrunk and grown by eps (the tolerance band around edges): every
// shrunk interval lies in a span, every span lies in a grown interval.
struct Sandwich {
  std::uint64_t pixels = 0, covered = 0, edge = 0, bad = 0;
};
void checkPixel(const DBuffer& db, const Ray& r, std::uint32_t pixel, const std::vector<WorldBox>& boxes, double eps,
                Sandwich& st) {
  const auto spans = db.spans(pixel);
  const Intervals inner = bruteUnion(r, boxes, -eps), outer = bruteUnion(r, boxes, eps);
  ++st.pixels;
  if (!spans.empty()) ++st.covered;
  if (inner.size() != outer.size()) ++st.edge;
  auto tol = [](double t) { return 1e-4 + 2e-7 * std::abs(t); };
  bool ok = true;
  for (const auto& [a, b] : inner) {
    bool in = false;
    for (const auto& s : spans) in = in || (s.tIn <= a + tol(a) && s.tOut >= b - tol(b));
    ok = ok && in;
  }
  for (const auto& s : spans) {
    bool in = false;
    for (const auto& [a, b] : outer) in = in || (s.tIn >= a - tol(a) && s.tOut <= b + tol(b));
    ok = ok && in;
  }
  if (!ok) {
    if (st.bad < 5) {
      std::string msg = "pixel " + std::to_string(pixel) + " spans";
      for (const auto& s : spans) msg += " [" + std::to_string(s.tIn) + "," + std::to_string(s.tOut) + "]";
      msg += " inner";
      for (const auto& [a, b] : inner) msg += " [" + std::to_string(a) + "," + std::to_string(b) + "]";
      msg += " outer";
      for (const auto& [a, b] : outer) msg += " [" + std::to_string(a) + "," + std::to_string(b) + "]";
      ADD_FAILURE() << msg;
    }
    ++st.bad;
  }
}

WorldBox randomBox(std::mt19937& rng, const Vec3& centre, double size) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Vec3 half = Vec3(0.05 + u(rng), 0.05 + u(rng), 0.05 + u(rng)) * (0.5 * size);
  return {centre - half, centre + half};
}

// ---------------------------------------------------------------------------

TEST(PixelRays, MatchCameraBitwise) {
  std::mt19937 rng(7);
  const Grid g = testGrid();
  for (int v = 0; v < 6; ++v) {
    const Camera c = randomCamera(rng, g, v % 2 ? Projection::Orthographic : Projection::Perspective, v == 4, 31, 17);
    const pp5::PixelRays rays(c);
    for (int y = 0; y < c.height; ++y)
      for (int x = 0; x < c.width; ++x) {
        const Ray a = c.pixelRay(x, y), b = rays.ray(x, y);
        ASSERT_EQ(a.origin, b.origin);
        ASSERT_EQ(a.dir, b.dir);
      }
    const Vec3 p = gridCentre(g) + Vec3(3.0, -2.0, 1.5);
    const auto pr = c.project(p);
    if (pr) {
      const auto q = rays.toPixel(rays.toCamera(p));
      EXPECT_NEAR(q.x, pr->px, 1e-9);
      EXPECT_NEAR(q.y, pr->py, 1e-9);
    }
  }
}

TEST(PixelRays, RowThroughBoxIsIntersectBoxBitwise) {
  // The lattice's two-lanes-at-a-time ray-box test against the scalar one,
  // pixel by pixel: random views and boxes, the eye inside the box, and views
  // straight down an axis, whose rays run parallel to the box's faces (a zero
  // direction component: the scalar test's other branch).
  std::mt19937 rng(5);
  const Grid g = testGrid();
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::uint64_t hits = 0, misses = 0, flat = 0;
  auto check = [&](const Camera& c, const WorldBox& b) {
    const pp5::PixelRays rays(c);
    std::vector<double> tIn(c.width), tOut(c.width);
    std::vector<std::uint8_t> hit(c.width);
    for (int y = 0; y < c.height; ++y) {
      const int x0 = y % 3;  // odd and even starts, and a last lone pixel
      rays.rowThroughBox(y, x0, c.width, b.lo, b.hi, tIn.data(), tOut.data(), hit.data());
      for (int x = x0; x < c.width; ++x) {
        const Ray r = rays.ray(x, y);
        flat += r.dir.x == 0.0 || r.dir.y == 0.0 || r.dir.z == 0.0;
        double a, e;
        const bool h = pp5::intersectBox(r, b.lo, b.hi, a, e);
        ASSERT_EQ(hit[x - x0] != 0, h) << x << ", " << y;
        if (!h) {
          ++misses;
          continue;
        }
        ++hits;
        ASSERT_EQ(std::bit_cast<std::uint64_t>(tIn[x - x0]), std::bit_cast<std::uint64_t>(a)) << x << ", " << y;
        ASSERT_EQ(std::bit_cast<std::uint64_t>(tOut[x - x0]), std::bit_cast<std::uint64_t>(e)) << x << ", " << y;
      }
    }
  };
  const Vec3 ext = g.maxCorner() - g.minCorner();
  for (int view = 0; view < 12; ++view) {
    const Projection proj = view % 2 ? Projection::Orthographic : Projection::Perspective;
    const Camera c = randomCamera(rng, g, proj, view % 4 >= 2, 37, 23);
    check(c, {g.minCorner(), g.maxCorner()});
    check(c, randomBox(rng, g.minCorner() + Vec3(u(rng), u(rng), u(rng)) * ext, 5.0 + 20.0 * u(rng)));
  }
  // Down the z axis, odd image sizes: the middle column and row have rays
  // with zero x or y components, and orthographic rays have both.
  for (const Projection proj : {Projection::Perspective, Projection::Orthographic}) {
    Camera c;
    c.projection = proj;
    c.width = 31;
    c.height = 21;
    c.target = gridCentre(g);
    c.eye = c.target + Vec3(0.0, 0.0, 300.0);
    c.up = Vec3(0.0, 1.0, 0.0);
    c.orthoHeightMm = 1.5 * ext.y;
    check(c, {g.minCorner(), g.maxCorner()});
    // Rays that run along a face plane: a box whose x face lies on the middle column's rays.
    check(c, {Vec3(c.eye.x, g.minCorner().y, g.minCorner().z), g.maxCorner()});
  }
  EXPECT_GT(hits, 1000u);
  EXPECT_GT(misses, 100u);
  EXPECT_GT(flat, 100u);
}

TEST(DBuffer, MatchesBruteForceRayBoxIntersections) {
  std::mt19937 rng(1991);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const Grid g = testGrid();
  const Vec3 ext = g.maxCorner() - g.minCorner();
  Sandwich st;
  int eyeInBox = 0, behind = 0;
  // One D-buffer for every view, as a GP keeps it: what it keeps per camera
  // (the perspective rays) must follow the camera.
  DBuffer db;
  for (int view = 0; view < 48; ++view) {
    const Projection proj = view % 2 ? Projection::Orthographic : Projection::Perspective;
    const int kind = (view / 2) % 4;  // 0 outside, 1 eye in grid, 2 eye in a box, 3 box across the eye plane
    const Camera c = randomCamera(rng, g, proj, kind != 0);
    std::vector<WorldBox> boxes;
    const int n = 1 + static_cast<int>(u(rng) * 3.0);
    for (int i = 0; i < n; ++i)
      boxes.push_back(randomBox(rng, g.minCorner() + Vec3(u(rng), u(rng), u(rng)) * ext, 10.0 + 30.0 * u(rng)));
    const pp5::PixelRays rays(c);
    if (kind == 2) {
      boxes[0] = randomBox(rng, c.eye, 12.0);
      boxes[0].lo = glm::min(boxes[0].lo, c.eye - Vec3(0.5));
      boxes[0].hi = glm::max(boxes[0].hi, c.eye + Vec3(0.5));
      ++eyeInBox;
    }
    if (kind == 3) {
      // Centred beside the eye, so the near plane cuts it.
      boxes[0] = randomBox(rng, c.eye + rays.right() * (3.0 + 4.0 * u(rng)) + rays.up() * 2.0 * (u(rng) - 0.5), 14.0);
      ++behind;
    }
    db.build(c, boxes);
    EXPECT_EQ(db.stats().spanMerges, 0u);  // at most 3 boxes: no span limit reached
    for (int y = 0; y < c.height; ++y)
      for (int x = 0; x < c.width; ++x) {
        const auto p = static_cast<std::uint32_t>(y * c.width + x);
        checkPixel(db, rays.ray(x, y), p, boxes, 1e-6 * glm::length(ext), st);
      }
    if (kind == 2 && proj == Projection::Perspective) {
      // Every ray from inside a box starts in it.
      ASSERT_EQ(db.touched().size(), static_cast<std::size_t>(c.width * c.height));
      for (const auto p : db.touched()) EXPECT_EQ(db.spans(p).front().tIn, 0.0f);
    }
    // The touched list is exactly the pixels with spans, ascending.
    std::uint64_t withSpans = 0;
    for (std::uint32_t p = 0; p < static_cast<std::uint32_t>(c.width * c.height); ++p) withSpans += !db.spans(p).empty();
    EXPECT_EQ(withSpans, db.touched().size());
    EXPECT_TRUE(std::is_sorted(db.touched().begin(), db.touched().end()));
  }
  EXPECT_EQ(st.bad, 0u);
  EXPECT_GT(st.covered, st.pixels / 10);
  EXPECT_LT(st.edge, st.pixels / 1000 + 5);  // pixels in the tolerance band
  EXPECT_GT(eyeInBox, 0);
  EXPECT_GT(behind, 0);
}

TEST(DBuffer, RaysKeptPerCameraCoverEveryPixelABoxNeeds) {
  // The D-buffer computes a perspective ray the first time a box needs it and
  // keeps it while the camera stays. Within a view, boxes on the left and the
  // right of the screen and then one between them (the same rows, a gap in
  // x); then a new view after one that needed every pixel.
  std::mt19937 rng(42);
  const Grid g = testGrid();
  DBuffer db;
  Sandwich st;
  for (int view = 0; view < 4; ++view) {
    const Camera c = randomCamera(rng, g, Projection::Perspective, false);
    const pp5::PixelRays rays(c);
    const Vec3 mid = gridCentre(g);
    const Vec3 side = rays.right() * 18.0;
    std::vector<WorldBox> boxes = {{mid - side - Vec3(4.0), mid - side + Vec3(4.0)},
                                   {mid + side - Vec3(4.0), mid + side + Vec3(4.0)},
                                   {mid - Vec3(5.0), mid + Vec3(5.0)}};
    if (view == 2) boxes.push_back({g.minCorner() - Vec3(50.0), g.maxCorner() + Vec3(50.0)});  // the whole screen
    db.build(c, boxes);
    for (int y = 0; y < c.height; ++y)
      for (int x = 0; x < c.width; ++x)
        checkPixel(db, rays.ray(x, y), static_cast<std::uint32_t>(y * c.width + x), boxes, 1e-6, st);
  }
  EXPECT_EQ(st.bad, 0u);
  EXPECT_GT(st.covered, st.pixels / 20);
}

TEST(DBuffer, ManyBoxesAlongARayKeepAConservativeUnion) {
  Camera c;
  c.eye = Vec3(0, 0, 100);
  c.target = Vec3(0, 0, 0);
  c.up = Vec3(0, 1, 0);
  c.width = c.height = 33;
  // Six thin slabs one behind the other: six intervals for the middle pixel.
  std::vector<WorldBox> boxes;
  for (int i = 0; i < 6; ++i) boxes.push_back({Vec3(-5, -5, -30.0 + 10 * i), Vec3(5, 5, -28.0 + 10 * i)});
  DBuffer db;
  db.build(c, boxes);
  const auto mid = static_cast<std::uint32_t>(16 * 33 + 16);
  const auto sp = db.spans(mid);
  ASSERT_EQ(sp.size(), static_cast<std::size_t>(DBuffer::kMaxSpans));
  EXPECT_GT(db.stats().spanMerges, 0u);
  for (const auto& b : boxes) {  // each slab is still inside some span
    const double t0 = 100.0 - b.hi.z, t1 = 100.0 - b.lo.z;
    bool in = false;
    for (const auto& s : sp) in = in || (s.tIn <= t0 + 1e-4 && s.tOut >= t1 - 1e-4);
    EXPECT_TRUE(in) << t0 << " " << t1;
  }
}

TEST(SampleLattice, KnownPointProjectsToItsPixelAndSample) {
  Grid g;
  g.origin = Vec3(-10.0);
  g.spacing = Vec3(1.0);
  g.dims = Index3(21);
  for (const Projection proj : {Projection::Perspective, Projection::Orthographic}) {
    SCOPED_TRACE(proj == Projection::Perspective ? "perspective" : "orthographic");
    Camera c;
    c.projection = proj;
    c.eye = Vec3(0, 0, 100);
    c.target = Vec3(0.0);
    c.up = Vec3(0, 1, 0);
    c.width = c.height = 63;  // odd: the middle pixel's centre is on the axis
    c.fovYDeg = 30.0;
    c.orthoHeightMm = 63.0;  // 1 mm pixels
    const SampleLattice lat(c, g, 0.5, 512, 1);
    const std::uint32_t mid = 31 * 63 + 31;
    EXPECT_EQ(lat.t0(mid), 90.0f);  // enters at z = +10
    EXPECT_EQ(lat.count(mid), 41);  // z = 10 .. -10 in steps of 0.5
    const Vec3 p4 = lat.point(mid, 4);
    EXPECT_NEAR(glm::length(p4 - Vec3(0, 0, 8)), 0.0, 1e-12);
    const auto pr = c.project(p4);
    ASSERT_TRUE(pr);
    EXPECT_NEAR(pr->px, 31.5, 1e-9);
    EXPECT_NEAR(pr->py, 31.5, 1e-9);
    const glm::vec3 v4 = lat.voxelRay(mid).at(4);
    EXPECT_NEAR(v4.x, 10.0f, 1e-5);
    EXPECT_NEAR(v4.y, 10.0f, 1e-5);
    EXPECT_NEAR(v4.z, 18.0f, 1e-5);
    // An off-axis point: the pixel it projects into, and the sample nearest it
    // on that pixel's ray.
    const Vec3 q(3.0, -2.0, 5.0);
    const auto qp = c.project(q);
    ASSERT_TRUE(qp);
    const int px = static_cast<int>(std::floor(qp->px)), py = static_cast<int>(std::floor(qp->py));
    EXPECT_GT(px, 31);  // +x is to the right, -y is down
    EXPECT_GT(py, 31);
    const auto pixel = static_cast<std::uint32_t>(py * 63 + px);
    const Ray r = lat.rays().ray(px, py);
    const double tq = glm::dot(q - r.origin, r.dir);
    const double lateral = glm::length(q - (r.origin + r.dir * tq));
    // Within half a pixel's diagonal at that depth.
    const double pixelMm = proj == Projection::Orthographic ? 1.0 : 2.0 * tq * std::tan(glm::radians(15.0)) / 63.0;
    EXPECT_LE(lateral, 0.7072 * pixelMm);
    const auto k = static_cast<std::uint32_t>(std::lround((tq - lat.t0(pixel)) / lat.step()));
    EXPECT_LT(k, lat.count(pixel));
    EXPECT_LE(glm::length(lat.point(pixel, k) - q), 0.5 * lat.step() + lateral + 1e-9);
    if (proj == Projection::Orthographic) {
      // Pixel (34, 33) is centred on x = 3, y = -2: the sample is on the point.
      EXPECT_EQ(px, 34);
      EXPECT_EQ(py, 33);
      EXPECT_EQ(k, 10u);
      EXPECT_NEAR(glm::length(lat.point(pixel, k) - q), 0.0, 1e-9);
    }
  }
}

// Entry and exit by intersecting the six face rectangles: independent of
// the slab test the lattice uses.
bool faceEntry(const Ray& r, const Vec3& lo, const Vec3& hi, double& tIn, double& tOut) {
  std::vector<double> ts;
  for (int a = 0; a < 3; ++a) {
    if (r.dir[a] == 0.0) continue;
    for (const double c : {lo[a], hi[a]}) {
      const double t = (c - r.origin[a]) / r.dir[a];
      const Vec3 p = r.origin + r.dir * t;
      bool inside = true;
      for (int b = 0; b < 3; ++b)
        if (b != a) inside = inside && p[b] >= lo[b] - 1e-9 && p[b] <= hi[b] + 1e-9;
      if (inside) ts.push_back(t);
    }
  }
  if (ts.empty()) return false;
  tIn = *std::min_element(ts.begin(), ts.end());
  tOut = *std::max_element(ts.begin(), ts.end());
  return true;
}

TEST(SampleLattice, AgreesWithBruteForceEntryAndIsReproducible) {
  std::mt19937 rng(42);
  const Grid g = testGrid();
  for (int view = 0; view < 16; ++view) {
    const Projection proj = view % 2 ? Projection::Orthographic : Projection::Perspective;
    const Camera c = randomCamera(rng, g, proj, view % 4 >= 2);
    const double step = 0.3 + 0.2 * (view % 3);
    const int maxSamples = view % 5 == 0 ? 40 : 512;
    const SampleLattice lat(c, g, step, maxSamples, 1);
    std::uint64_t hits = 0;
    for (int y = 0; y < c.height; ++y)
      for (int x = 0; x < c.width; ++x) {
        const auto p = static_cast<std::uint32_t>(y * c.width + x);
        const Ray r = c.pixelRay(x, y);
        double tIn, tOut;
        const bool hit = faceEntry(r, g.minCorner(), g.maxCorner(), tIn, tOut) && tOut >= 0.0;
        if (!hit) {
          EXPECT_EQ(lat.count(p), 0) << p;
          continue;
        }
        ++hits;
        const double t0 = std::max(tIn, 0.0);
        EXPECT_NEAR(lat.t0(p), t0, 1e-5 * (1.0 + t0)) << p;
        const double n = std::floor((tOut - t0) / step) + 1.0;
        const double frac = (tOut - t0) / step - std::floor((tOut - t0) / step);
        if (n > maxSamples) {
          EXPECT_EQ(lat.count(p), maxSamples);
        } else if (frac > 1e-4 && frac < 1.0 - 1e-4) {
          EXPECT_EQ(lat.count(p), static_cast<int>(n)) << p;
        } else {
          EXPECT_NEAR(lat.count(p), n, 1.0) << p;
        }
        // Every sample is inside the box.
        for (const std::uint32_t k : {0u, static_cast<std::uint32_t>(lat.count(p) - 1)}) {
          const Vec3 q = lat.point(p, k);
          EXPECT_TRUE(glm::all(glm::greaterThanEqual(q, g.minCorner() - Vec3(1e-6))) &&
                      glm::all(glm::lessThanEqual(q, g.maxCorner() + Vec3(1e-6))))
              << p << " k " << k;
        }
      }
    EXPECT_GT(hits, 0u);
    for (const int threads : {1, 2, 3}) {
      const SampleLattice again(c, g, step, maxSamples, threads);
      ASSERT_EQ(0, std::memcmp(again.t0s().data(), lat.t0s().data(), lat.t0s().size_bytes()));
      ASSERT_EQ(0, std::memcmp(again.counts().data(), lat.counts().data(), lat.counts().size_bytes()));
    }
  }
}

// ---------------------------------------------------------------------------
// Sampling

std::uint32_t hash3(std::int64_t i, std::int64_t j, std::int64_t k, std::uint32_t seed) {
  std::uint32_t h = static_cast<std::uint32_t>(i) * 73856093u ^ static_cast<std::uint32_t>(j) * 19349663u ^
                    static_cast<std::uint32_t>(k) * 83492791u ^ seed * 2654435761u;
  h ^= h >> 13;
  h *= 0x5bd1e995u;
  h ^= h >> 15;
  return h;
}

// Premultiplied random voxels inside a few blobs, transparent elsewhere, so
// that the empty-space map has both kinds of bricks.
ShadeBuffer blobShade(const Grid& g, std::uint32_t seed) {
  ShadeBuffer s(g);
  const Vec3 c1 = g.voxelToWorld(Vec3(g.dims) * 0.35), c2 = g.voxelToWorld(Vec3(g.dims) * Vec3(0.7, 0.6, 0.55));
  for (std::int64_t k = 0; k < g.dims.z; ++k)
    for (std::int64_t j = 0; j < g.dims.y; ++j)
      for (std::int64_t i = 0; i < g.dims.x; ++i) {
        const Vec3 p = g.voxelToWorld(Vec3(i, j, k));
        if (glm::length(p - c1) > 9.0 && glm::length(p - c2) > 6.0) continue;
        const std::uint32_t h = hash3(i, j, k, seed);
        if (h % 5 == 0) continue;  // some transparent voxels inside too
        ShadeVoxel& v = s.at(g.linear(i, j, k));
        v.a = static_cast<std::uint8_t>(1 + (h >> 8) % 255);
        v.r = static_cast<std::uint8_t>(((h >> 16) & 0xff) * v.a / 255);
        v.g = static_cast<std::uint8_t>(((h >> 24) & 0xff) * v.a / 255);
        v.b = static_cast<std::uint8_t>(v.a / 2);
      }
  return s;
}

using Key = std::pair<std::uint32_t, std::uint32_t>;
std::map<Key, RaySample> byKey(const std::vector<RaySample>& v) {
  std::map<Key, RaySample> m;
  for (const auto& s : v) EXPECT_TRUE(m.emplace(Key{s.pixel, s.k}, s).second) << "duplicate " << s.pixel << " " << s.k;
  return m;
}

bool sameBits(const RaySample& a, const RaySample& b) { return std::memcmp(&a, &b, sizeof(RaySample)) == 0; }

RenderSettings settingsFor(int threads, double unit = 1.0) {
  RenderSettings s;
  s.threads = threads;
  s.opacityUnitMm = unit;
  return s;
}

std::vector<RaySample> runAll(const ShadeBuffer& shade, const SampleLattice& lat, int threads,
                              const pp5::gp::EmptySpaceMap* space = nullptr) {
  pp5::gp::SampleCollector col;
  pp5::gp::sampleAll(shade, lat, settingsFor(threads), col, space);
  return col.samples();
}

std::vector<RaySample> runRegion(const ShadeBuffer& shade, const SampleLattice& lat, const DBuffer& db, int threads,
                                 const pp5::gp::EmptySpaceMap* space = nullptr) {
  pp5::gp::SampleCollector col;
  pp5::gp::sampleRegion(shade, lat, db, settingsFor(threads), col, space);
  return col.samples();
}

// Distance in voxels from a voxel position to the closed box [lo, hi].
double boxDistance(const glm::vec3& p, const Vec3& lo, const Vec3& hi) {
  double d = 0.0;
  for (int a = 0; a < 3; ++a) d = std::max(d, std::max(lo[a] - p[a], p[a] - hi[a]));
  return d;
}

TEST(RaySampler, RegionEqualsFullRenderRestrictedToTheStencil) {
  std::mt19937 rng(2024);
  std::uniform_int_distribution<int> ui(0, 1 << 30);
  const Grid g = testGrid();
  ShadeBuffer shade = blobShade(g, 1);
  struct Case {
    Projection proj;
    bool eyeInside;
    Box3 box;
  };
  const std::vector<Case> cases = {
      {Projection::Perspective, false, {{10, 8, 6}, {17, 15, 12}}},
      {Projection::Orthographic, false, {{20, 12, 9}, {26, 20, 16}}},
      {Projection::Perspective, true, {{8, 10, 8}, {22, 14, 13}}},
      {Projection::Perspective, false, {{0, 0, 0}, {5, 33, 4}}},      // on the grid's faces
      {Projection::Orthographic, true, {{30, 25, 20}, {40, 33, 31}}},  // the far corner
  };
  std::uint64_t touchingTotal = 0, slackTotal = 0;
  for (std::size_t ci = 0; ci < cases.size(); ++ci) {
    SCOPED_TRACE("case " + std::to_string(ci));
    const Case& cs = cases[ci];
    const Camera c = randomCamera(rng, g, cs.proj, cs.eyeInside, 64, 56);
    const SampleLattice lat(c, g, 0.45, 512, 1);
    const pp5::gp::EmptySpaceMap space(shade, 1);
    const auto boxes = pp5::gp::stencilBoxes(g, std::span<const Box3>(&cs.box, 1));
    ASSERT_EQ(boxes.size(), 1u);
    DBuffer db;
    db.build(c, boxes);
    const auto all = byKey(runAll(shade, lat, 1, &space));
    const auto regionVec = runRegion(shade, lat, db, 1, &space);
    const auto region = byKey(regionVec);
    EXPECT_EQ(region.size(), regionVec.size());
    EXPECT_EQ(byKey(runRegion(shade, lat, db, 1)).size(), region.size());  // the map only saves work
    const Vec3 lo = Vec3(cs.box.lo) - 1.0, hi = Vec3(cs.box.hi);           // the stencil's reach
    std::uint64_t touching = 0;
    for (std::uint32_t p = 0; p < lat.pixelCount(); ++p)
      for (std::uint32_t k = 0; k < lat.count(p); ++k) {
        const Index3 cell = pp5::gp::stencilCell(lat, p, k);
        const bool touches = glm::all(glm::greaterThanEqual(cell, cs.box.lo - Index3(1))) &&
                             glm::all(glm::lessThan(cell, cs.box.hi));
        const auto r = region.find({p, k});
        if (touches) {
          ++touching;
          ASSERT_NE(r, region.end()) << "missing pixel " << p << " k " << k;
        }
        if (r == region.end()) continue;
        if (!touches) {
          // Only within the slack of the grow rule.
          EXPECT_LE(boxDistance(lat.voxelRay(p).at(k), lo, hi), pp5::gp::kStencilSlackVoxels + 1e-4);
          ++slackTotal;
        }
        const auto a = all.find({p, k});
        const RaySample expected = a != all.end() ? a->second : RaySample{p, k, 0, 0, 0, 0};
        ASSERT_TRUE(sameBits(r->second, expected)) << p << " " << k;
      }
    for (const auto& [key, s] : region) EXPECT_LT(key.second, lat.count(key.first));
    EXPECT_GT(touching, 100u);
    touchingTotal += touching;

    // Changing voxels inside the box changes only samples of the region, and
    // re-sampling the region gives the full render's new values.
    ShadeBuffer changed = shade;
    for (std::int64_t k = cs.box.lo.z; k < cs.box.hi.z; ++k)
      for (std::int64_t j = cs.box.lo.y; j < cs.box.hi.y; ++j)
        for (std::int64_t i = cs.box.lo.x; i < cs.box.hi.x; ++i) {
          ShadeVoxel& v = changed.at(g.linear(i, j, k));
          v.a = static_cast<std::uint8_t>(ui(rng) % 256);
          v.r = v.g = v.b = static_cast<std::uint8_t>(v.a / 3);
        }
    pp5::gp::EmptySpaceMap space2 = space;
    space2.update(changed, std::span<const Box3>(&cs.box, 1));
    const auto all2 = byKey(runAll(changed, lat, 1, &space2));
    const auto region2 = byKey(runRegion(changed, lat, db, 1, &space2));
    auto valueOf = [](const std::map<Key, RaySample>& m, Key k) {
      const auto it = m.find(k);
      return it != m.end() ? it->second : RaySample{k.first, k.second, 0, 0, 0, 0};
    };
    std::set<Key> keys;
    for (const auto& [k, s] : all) keys.insert(k);
    for (const auto& [k, s] : all2) keys.insert(k);
    std::uint64_t diffs = 0;
    for (const Key& k : keys)
      if (!sameBits(valueOf(all, k), valueOf(all2, k))) {
        ++diffs;
        ASSERT_TRUE(region2.count(k)) << "changed sample outside the region: " << k.first << " " << k.second;
      }
    EXPECT_GT(diffs, 0u);
    for (const auto& [k, s] : region2) ASSERT_TRUE(sameBits(s, valueOf(all2, k)));
  }
  // The slack adds a sliver, not a shell.
  EXPECT_LT(slackTotal, touchingTotal / 50 + 10);
}

TEST(RaySampler, OpacityCorrectionOfAUniformShade) {
  Grid g;
  g.origin = Vec3(0.0);
  g.spacing = Vec3(0.8);
  g.dims = Index3(12, 10, 9);
  ShadeBuffer shade(g);
  const ShadeVoxel v{60, 90, 120, 150};
  for (std::uint64_t i = 0; i < g.voxelCount(); ++i) shade.at(i) = v;
  Camera c;
  c.eye = Vec3(30, -40, 50);
  c.target = gridCentre(g);
  c.up = Vec3(0, 0, 1);
  c.width = c.height = 24;
  for (const auto& [step, unit] : std::vector<std::pair<double, double>>{{0.4, 1.0}, {1.0, 1.0}, {0.25, 0.5}, {2.0, 0.7}}) {
    const SampleLattice lat(c, g, step, 512, 1);
    const double a = 150.0 / 255.0;
    const double expected = 1.0 - std::pow(1.0 - a, step / unit);
    pp5::gp::SampleCollector col;
    pp5::gp::sampleAll(shade, lat, settingsFor(1, unit), col);
    const auto samples = col.samples();
    EXPECT_EQ(samples.size(), lat.totalSamples());
    for (const auto& s : samples) {
      ASSERT_NEAR(s.a, expected, 1e-6) << step << " " << unit;
      ASSERT_NEAR(s.r, 60.0 / 150.0 * expected, 1e-6);
      ASSERT_NEAR(s.g, 90.0 / 150.0 * expected, 1e-6);
      ASSERT_NEAR(s.b, 120.0 / 150.0 * expected, 1e-6);
      ASSERT_TRUE(sameBits(s, pp5::gp::sampleAt(shade, lat, settingsFor(1, unit), s.pixel, s.k)));
    }
  }
  // The power itself, over the whole range, against libm.
  for (const double e : {0.01, 0.4, 1.0, 2.5, 100.0})
    for (int i = 0; i <= 4000; ++i) {
      const float a = static_cast<float>(i) / 4000.0f;
      const double ref = 1.0 - std::pow(1.0 - static_cast<double>(a), e);
      ASSERT_NEAR(pp5::gp::correctOpacity(a, static_cast<float>(e)), ref, 1e-7 + 1e-6 * ref) << a << " " << e;
    }
  EXPECT_EQ(pp5::gp::correctOpacity(0.0f, 0.4f), 0.0f);
  EXPECT_EQ(pp5::gp::correctOpacity(1.0f, 0.4f), 1.0f);
}

TEST(RaySampler, SameBitsForAnyThreadCountAndWithOrWithoutSkipping) {
  std::mt19937 rng(5);
  const Grid g = testGrid();
  const ShadeBuffer shade = blobShade(g, 9);
  ShadeBuffer opaque(g);  // its map has no empty brick: no skipping at all
  for (std::uint64_t i = 0; i < g.voxelCount(); ++i) opaque.at(i).a = 1;
  const pp5::gp::EmptySpaceMap noSkip(opaque, 1), space(shade, 2);
  EXPECT_GT(space.emptyFraction(), 0.3);
  for (const Projection proj : {Projection::Perspective, Projection::Orthographic}) {
    const Camera c = randomCamera(rng, g, proj, false, 80, 70);
    const SampleLattice lat(c, g, 0.4, 512, 2);
    const auto ref = runAll(shade, lat, 1, &noSkip);
    EXPECT_GT(ref.size(), 1000u);
    const Box3 box{{12, 10, 8}, {20, 18, 14}};
    DBuffer db;
    db.build(c, pp5::gp::stencilBoxes(g, std::span<const Box3>(&box, 1), 1));
    const auto refRegion = runRegion(shade, lat, db, 1);
    EXPECT_GT(refRegion.size(), 100u);
    for (const int t : {1, 2, 3}) {
      const auto a = runAll(shade, lat, t, &space);
      ASSERT_EQ(a.size(), ref.size()) << t;
      EXPECT_EQ(0, std::memcmp(a.data(), ref.data(), a.size() * sizeof(RaySample))) << t;
      const auto r = runRegion(shade, lat, db, t, &space);
      ASSERT_EQ(r.size(), refRegion.size()) << t;
      EXPECT_EQ(0, std::memcmp(r.data(), refRegion.data(), r.size() * sizeof(RaySample))) << t;
    }
    // Batches never exceed the limit and never straddle a tile.
    pp5::gp::SamplerOptions opt;
    opt.tileSize = 16;
    opt.batchSamples = 100;
    std::vector<std::uint32_t> tileOf;
    pp5::gp::CallbackSink sink([&](int, std::uint32_t tile, std::span<const RaySample> s) {
      EXPECT_LE(s.size(), 100u);
      for (const auto& x : s) {
        const std::uint32_t px = x.pixel % 80, py = x.pixel / 80;
        EXPECT_EQ(tile, (py / 16) * 5 + px / 16);
      }
    });
    pp5::gp::sampleAll(shade, lat, settingsFor(2), sink, &space, opt);
  }
}

// The bricks of cells (8 per side; cell c reads voxels c and c + 1) with a
// visible voxel, by brute force.
std::vector<Index3> occupiedBricks(const Grid& g, const ShadeBuffer& s, const Index3& bd) {
  std::vector<Index3> occ;
  for (std::int64_t bk = 0; bk < bd.z; ++bk)
    for (std::int64_t bj = 0; bj < bd.y; ++bj)
      for (std::int64_t bi = 0; bi < bd.x; ++bi) {
        bool any = false;
        for (std::int64_t k = bk * 8; k <= std::min(bk * 8 + 8, g.dims.z - 1); ++k)
          for (std::int64_t j = bj * 8; j <= std::min(bj * 8 + 8, g.dims.y - 1); ++j)
            for (std::int64_t i = bi * 8; i <= std::min(bi * 8 + 8, g.dims.x - 1); ++i)
              any = any || s.at(g.linear(i, j, k)).a != 0;
        if (any) occ.push_back(Index3(bi, bj, bk));
      }
  return occ;
}

// Chessboard distance from brick b to the nearest of `occ`, 255 if none (or farther).
int chessboardDistance(const std::vector<Index3>& occ, const Index3& b) {
  int best = 255;
  for (const Index3& o : occ)
    best = std::min<int>(best, static_cast<int>(std::max({std::abs(o.x - b.x), std::abs(o.y - b.y), std::abs(o.z - b.z)})));
  return best;
}

// Every cell's bit against its 8 voxels, brute force.
void expectCellBits(const pp5::gp::EmptySpaceMap& m, const ShadeBuffer& s) {
  const Grid& g = s.grid();
  ASSERT_TRUE(m.hasCellBits());
  for (std::int64_t k = 0; k + 1 < g.dims.z; ++k)
    for (std::int64_t j = 0; j + 1 < g.dims.y; ++j)
      for (std::int64_t i = 0; i + 1 < g.dims.x; ++i) {
        bool visible = false;
        for (int c = 0; c < 8; ++c) visible |= s.at(g.linear(i + (c & 1), j + ((c >> 1) & 1), k + (c >> 2))).a > 0;
        ASSERT_EQ(m.cellVisible(static_cast<std::int64_t>(g.linear(i, j, k))), visible) << i << " " << j << " " << k;
      }
}

TEST(EmptySpaceMap, DistancesAreExactAndUpdatesEqualRebuilds) {
  const Grid g = testGrid();
  ShadeBuffer shade = blobShade(g, 3);
  pp5::gp::EmptySpaceMap m(shade, 1);
  const Index3 bd = m.brickDims();
  EXPECT_EQ(bd, Index3(5, 4, 4));  // ceil((dims - 1) / 8)
  auto check = [&](const pp5::gp::EmptySpaceMap& map, const ShadeBuffer& s) {
    const std::vector<Index3> occ = occupiedBricks(g, s, bd);
    for (std::int64_t bk = 0; bk < bd.z; ++bk)
      for (std::int64_t bj = 0; bj < bd.y; ++bj)
        for (std::int64_t bi = 0; bi < bd.x; ++bi)
          ASSERT_EQ(map.distance(bi, bj, bk), chessboardDistance(occ, Index3(bi, bj, bk))) << bi << " " << bj << " " << bk;
  };
  check(m, shade);
  expectCellBits(m, shade);
  // A single opaque voxel on a brick boundary marks the bricks of both cells
  // that read it.
  const Box3 box{{16, 24, 8}, {17, 25, 9}};
  shade.at(g.linear(16, 24, 8)).a = 7;
  m.update(shade, std::span<const Box3>(&box, 1));
  EXPECT_EQ(m.distance(1, 2, 0), 0);
  EXPECT_EQ(m.distance(2, 3, 1), 0);
  check(m, shade);
  expectCellBits(m, shade);
  // Clearing voxels: the update equals a rebuild.
  const Box3 clear{{0, 0, 0}, {20, 20, 20}};
  for (std::int64_t k = 0; k < 20; ++k)
    for (std::int64_t j = 0; j < 20; ++j)
      for (std::int64_t i = 0; i < 20; ++i) shade.at(g.linear(i, j, k)) = {};
  m.update(shade, std::span<const Box3>(&clear, 1));
  const pp5::gp::EmptySpaceMap rebuilt(shade, 2);
  EXPECT_EQ(0, std::memcmp(m.distances(), rebuilt.distances(), static_cast<std::size_t>(bd.x * bd.y * bd.z)));
  check(m, shade);
  expectCellBits(m, shade);
  expectCellBits(rebuilt, shade);
  // The brick level alone, as the sampler keeps the map before a change.
  pp5::gp::EmptySpaceMap bricks;
  bricks.assignBricks(m);
  EXPECT_FALSE(bricks.hasCellBits());
  EXPECT_EQ(bricks.brickDims(), bd);
  EXPECT_EQ(0, std::memcmp(bricks.distances(), m.distances(), static_cast<std::size_t>(bd.x * bd.y * bd.z)));
}

TEST(EmptySpaceMap, RandomUpdatesEqualRebuilds) {
  // Boxes of random voxels (mostly transparent, a few visible, some cleared),
  // each followed by an update with that box: the map always equals one built
  // from scratch, whether a brick was empty before (only the box's part of it
  // is read) or not (all of it is).
  const Grid g = testGrid();
  ShadeBuffer shade = blobShade(g, 3);
  pp5::gp::EmptySpaceMap m(shade, 1);
  const Index3 bd = m.brickDims();
  std::mt19937 rng(77);
  auto pick = [&](std::int64_t n) { return static_cast<std::int64_t>(rng() % static_cast<std::uint32_t>(n)); };
  for (int round = 0; round < 40; ++round) {
    Box3 b;
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = pick(g.dims[a]);
      b.hi[a] = std::min<std::int64_t>(g.dims[a], b.lo[a] + 1 + pick(12));
    }
    const int visibleEvery = round % 3 == 0 ? 0 : 40 + round;  // every third box clears
    for (std::int64_t k = b.lo.z; k < b.hi.z; ++k)
      for (std::int64_t j = b.lo.y; j < b.hi.y; ++j)
        for (std::int64_t i = b.lo.x; i < b.hi.x; ++i) {
          ShadeVoxel& v = shade.at(g.linear(i, j, k));
          v = {};
          if (visibleEvery > 0 && pick(visibleEvery) == 0) v.a = static_cast<std::uint8_t>(1 + pick(255));
        }
    m.update(shade, std::span<const Box3>(&b, 1));
    const pp5::gp::EmptySpaceMap rebuilt(shade, 1);
    ASSERT_EQ(0, std::memcmp(m.distances(), rebuilt.distances(), static_cast<std::size_t>(bd.x * bd.y * bd.z)))
        << "round " << round;
    EXPECT_EQ(m.occupiedCells().lo, rebuilt.occupiedCells().lo) << "round " << round;
    EXPECT_EQ(m.occupiedCells().hi, rebuilt.occupiedCells().hi) << "round " << round;
    SCOPED_TRACE(round);
    expectCellBits(m, shade);
  }
}

// Visible voxels added one at a time to a larger, empty map (each update
// makes at most a brick or two occupied, whose distances reach far across
// the map), and now and then one taken away: after each update the map
// equals one built from scratch, its occupied box included.
TEST(EmptySpaceMap, ScatteredVoxelsAddedOneByOneEqualRebuilds) {
  Grid g;
  g.spacing = Vec3(1.0);
  g.dims = Index3(8 * 13 + 1, 8 * 11 + 3, 8 * 9);
  ShadeBuffer shade(g);
  pp5::gp::EmptySpaceMap m(shade, 1);
  const Index3 bd = m.brickDims();
  std::mt19937 rng(2026);
  std::vector<std::int64_t> lit;
  int lowered = 0;
  for (int round = 0; round < 60; ++round) {
    std::int64_t v;
    if (round % 7 == 6 && !lit.empty()) {
      v = lit[rng() % lit.size()];  // taken away: distances rise
      shade.at(static_cast<std::size_t>(v)) = {};
    } else {
      v = static_cast<std::int64_t>(g.linear(rng() % g.dims.x, rng() % g.dims.y, rng() % g.dims.z));
      shade.at(static_cast<std::size_t>(v)) = ShadeVoxel{10, 20, 30, 40};
      lit.push_back(v);
    }
    const std::vector<std::uint8_t> before(m.distances(), m.distances() + bd.x * bd.y * bd.z);
    const Index3 at(v % g.dims.x, (v / g.dims.x) % g.dims.y, v / (g.dims.x * g.dims.y));
    const Box3 box{at, at + Index3(1)};
    m.update(shade, std::span<const Box3>(&box, 1));
    const pp5::gp::EmptySpaceMap rebuilt(shade, 1);
    ASSERT_EQ(0, std::memcmp(m.distances(), rebuilt.distances(), before.size())) << "round " << round;
    ASSERT_EQ(m.occupiedCells().lo, rebuilt.occupiedCells().lo) << "round " << round;
    ASSERT_EQ(m.occupiedCells().hi, rebuilt.occupiedCells().hi) << "round " << round;
    // Count the updates that lowered a distance two or more bricks away.
    for (std::size_t b = 0; b < before.size(); ++b)
      if (m.distances()[b] < before[b] && m.distances()[b] >= 2) {
        ++lowered;
        break;
      }
  }
  EXPECT_GT(lowered, 20);
}

// A larger map with a few scattered visible voxels (and none at all): the
// distances are the exact chessboard distances to the nearest occupied brick
// (255 where there is none), the box of occupied bricks is right, and the
// visible-voxel boxes hold every visible voxel and are disjoint.
TEST(EmptySpaceMap, DistancesExactOnAScatteredMapAndVisibleBoxesCoverEveryVisibleVoxel) {
  Grid g;
  g.spacing = Vec3(1.0);
  g.dims = Index3(8 * 13 + 1, 8 * 11 + 3, 8 * 9);  // 13 x 12 x 9 bricks of cells, some partial
  std::mt19937 rng(5);
  for (const int points : {0, 1, 7}) {
    ShadeBuffer s(g);
    for (int n = 0; n < points; ++n) {
      const std::int64_t i = rng() % g.dims.x, j = rng() % g.dims.y, k = rng() % g.dims.z;
      s.at(g.linear(i, j, k)) = ShadeVoxel{10, 20, 30, 40};
    }
    const pp5::gp::EmptySpaceMap m(s, 1);
    expectCellBits(m, s);
    const Index3 bd = m.brickDims();
    ASSERT_EQ(bd, Index3(13, 12, 9));
    const std::vector<Index3> occ = occupiedBricks(g, s, bd);
    for (std::int64_t bk = 0; bk < bd.z; ++bk)
      for (std::int64_t bj = 0; bj < bd.y; ++bj)
        for (std::int64_t bi = 0; bi < bd.x; ++bi)
          ASSERT_EQ(m.distance(bi, bj, bk), chessboardDistance(occ, Index3(bi, bj, bk)))
              << points << " points, brick " << bi << " " << bj << " " << bk;
    EXPECT_EQ(m.occupiedCells().empty(), occ.empty());

    // Every visible voxel in exactly one box; within a clip, only inside it.
    for (const Box3& within : {Box3{Index3(0), g.dims}, Box3{Index3(5, 17, 0), Index3(61, 90, 40)}}) {
      const std::vector<Box3> boxes = m.visibleVoxelBoxes(within);
      for (std::int64_t k = 0; k < g.dims.z; ++k)
        for (std::int64_t j = 0; j < g.dims.y; ++j)
          for (std::int64_t i = 0; i < g.dims.x; ++i) {
            int in = 0;
            for (const Box3& b : boxes) in += b.contains(i, j, k) ? 1 : 0;
            ASSERT_LE(in, 1) << i << " " << j << " " << k;
            if (s.at(g.linear(i, j, k)).a != 0 && within.contains(i, j, k)) {
              ASSERT_EQ(in, 1) << i << " " << j << " " << k;
            }
            if (!within.contains(i, j, k)) {
              ASSERT_EQ(in, 0);
            }
          }
      if (points == 0) {
        EXPECT_TRUE(boxes.empty());
      }
    }
  }
}

TEST(StencilBoxes, GrowRuleAndBrickMerging) {
  const Grid g = testGrid();
  const Box3 b{{5, 6, 7}, {9, 10, 11}};
  const auto w = pp5::gp::stencilBoxes(g, std::span<const Box3>(&b, 1), 1);
  ASSERT_EQ(w.size(), 1u);
  const double s = pp5::gp::kStencilSlackVoxels;
  // Voxels 4..9 after the extra voxel; samples with cell 3..9: points 3..10.
  EXPECT_NEAR(glm::length(w[0].lo - g.voxelToWorld(Vec3(3.0 - s, 4.0 - s, 5.0 - s))), 0.0, 1e-12);
  EXPECT_NEAR(glm::length(w[0].hi - g.voxelToWorld(Vec3(10.0 + s, 11.0 + s, 12.0 + s))), 0.0, 1e-12);
  // Clipped to the sampling box.
  const Box3 edge{{0, 0, 0}, {40, 2, 2}};
  const auto e = pp5::gp::stencilBoxes(g, std::span<const Box3>(&edge, 1));
  EXPECT_NEAR(glm::length(e[0].lo - g.voxelToWorld(Vec3(-s))), 0.0, 1e-12);
  EXPECT_NEAR(e[0].hi.x, g.voxelToWorld(Vec3(39.0 + s)).x, 1e-12);

  // Merged bricks cover exactly what the bricks one by one cover.
  std::mt19937 rng(11);
  for (int trial = 0; trial < 20; ++trial) {
    pp5::gp::DirtyRegion r(g, 8);
    for (int i = 0; i < 12; ++i) r.addBrick(rng() % 5, rng() % 5, rng() % 4);
    if (trial % 2) r = r.grown(3);
    const auto merged = pp5::gp::stencilBoxes(r);
    const auto bricks = r.boxes();
    const auto single = pp5::gp::stencilBoxes(g, bricks);
    EXPECT_LE(merged.size(), single.size());
    auto inside = [](const std::vector<WorldBox>& v, const Vec3& p) {
      for (const auto& b : v)
        if (glm::all(glm::greaterThanEqual(p, b.lo)) && glm::all(glm::lessThanEqual(p, b.hi))) return true;
      return false;
    };
    for (double z = -0.25; z < 31; z += 0.5)
      for (double y = -0.25; y < 33; y += 0.5)
        for (double x = -0.25; x < 40; x += 0.5) {
          const Vec3 p = g.voxelToWorld(Vec3(x, y, z));
          ASSERT_EQ(inside(merged, p), inside(single, p)) << x << " " << y << " " << z;
        }
  }
}

}  // namespace
