#include "reconstruction/splat_tent.hpp"

// The 1990 paper's reconstruction (Ohbuchi & Fuchs).
//
// Forward mapping. Every selected pixel p spreads its value over the voxels
// around it with the weight
//     w(x, p) = tent(du/hl) * tent(dv/ha) * tent(dn/he),  tent(t) = max(0, 1-|t|),
// where (du, dv, dn) = x - p in the slice's own orthonormal axes (lateral =
// image x, axial, normal), and a voxel keeps sum(w*v) and sum(w) over every
// pixel it ever received; its value is their ratio. The kernel's support is a
// box that rotates with the slice, so a slice changes exactly the voxels whose
// centres lie inside its oriented "support slab" (the pixel rectangle grown
// by the half-widths), and that slab is also its dirty region.
//
// The sums are evaluated voxel by voxel rather than pixel by pixel: a slice
// visits each voxel of its slab once and adds the contributions of every
// pixel whose kernel reaches it. It is the same sum as scattering each pixel,
// but each voxel is written once per slice, by one thread, with its terms in
// a fixed order, so the result is the same bits for any thread count and any
// split of the voxels, with no locks, and its output is refreshed in the same
// pass.
//
// A voxel does not visit those pixels one by one (about 11 x 3 of them for
// the default kernel and probe). The slice is planar, so dn is the same for
// every pixel and the weight splits into tent(dn) times an in-plane sum; and
// when the pixel grid is not sheared, pixel (c, r) sits at (u, v) =
// (c*sx, r*syv), so that sum is
//     sum_r tent(dv_r/ha) * P_r(U),   P_r(U) = sum_c tent((U - c*sx)/hl) * value(c, r)
// (and the same with the 0/1 mask for sum(w)). A row's "lateral profile" P_r
// is piecewise linear in U, with kinks only where a pixel's tent has one, at
// c*sx and c*sx +- hl: on three lattices of period sx. So each slice first
// computes every row's P_r and M_r at those knots (ProfileRow: fixed short
// sums of pixels, each knot's in a fixed order), and a voxel then only sums
// its few rows' profiles at the two knots around U, weighted by the axial
// tents, and interpolates linearly between them (inPlaneSums). That is exact
// up to float rounding, not an approximation: a knot on a pixel's kink gets
// exactly 0 from it, so a voxel that no selected pixel reaches gets exactly 0,
// and never a negative weight. A sheared pixel grid shifts each row's
// profile by r*eyu along u, and then each row has its own knot cell.
//
// Between consecutive frames that are farther apart than the kernel reaches,
// intermediate slices are interpolated (see fillInCount), and old data can be
// replaced when a region is scanned again (accumulate | motion_vector | decay,
// see the notes above TentReconstructor).

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <omp.h>
#if defined(__linux__)
#include <sys/mman.h>
#endif
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.hpp"
#include "reconstruction/fan_mask.hpp"
#include "reconstruction/slice_geometry.hpp"
#include "reconstruction/tent_kernel.hpp"
#include "reconstruction/tent_reconstructor.hpp"
#include "reconstruction/voxel_array.hpp"
#include "core/threads.hpp"

namespace pp5::gp {

namespace tent {


TentReconstructor::TentReconstructor(const Grid& g, const ReconSettings& s)
    : Reconstructor(g, s), mode_(checkedEnum(s.tent.replacement)) {
  if (!(s.tent.kernelLateralMm > 0.0) || !(s.tent.kernelAxialMm > 0.0) || !(s.tent.kernelElevationMm > 0.0))
    throw InputError(fmt::format("recon: the tent kernel's half-widths must be positive (got {} {} {} mm)",
                                 s.tent.kernelLateralMm, s.tent.kernelAxialMm, s.tent.kernelElevationMm));
  PP5_CHECK(g.voxelCount() > 0);
  hl_ = s.tent.kernelLateralMm;
  ha_ = s.tent.kernelAxialMm;
  he_ = s.tent.kernelElevationMm;
  threads_ = resolveThreads(s.threads);
  const auto n = static_cast<std::size_t>(g.voxelCount());
  // Volume::allocate, with huge pages asked for before the zero fill.
  checkGridFits(g, 4, "reconstruction output");
  output_.grid = g;
  output_.type = ScalarType::F32;
  output_.bytes.reserve(4 * n);
  adviseHugePages(output_.bytes.data(), 4 * n);
  output_.bytes.assign(4 * n, 0);
  acc_ = VoxelArray<float>(2 * n);
  if (mode_ == Replacement::Decay) {
    if (!(s.tent.decayTauS > 0.0)) throw InputError("recon.decay_tau_s must be positive");
    tLast_.assign(n, 0.0f);
  }
  if (mode_ == Replacement::MotionVector) {
    if (s.tent.motionVectorBrick < 1) throw InputError("recon.motion_vector_brick must be at least 1");
    if (!(s.tent.motionVectorNewWeight > 0.0 && s.tent.motionVectorNewWeight <= 1.0))
      throw InputError("recon.motion_vector_new_weight must be in (0, 1]");
    wNew_ = static_cast<float>(s.tent.motionVectorNewWeight);
    wOld_ = static_cast<float>(1.0 - s.tent.motionVectorNewWeight);
    baseV_.assign(n, 0.0f);
    baseW_.assign(n, 0.0f);
    const std::int64_t b = s.tent.motionVectorBrick;
    cellDims_ = (g.dims + Index3(b - 1)) / Index3(b);
    const auto cells = static_cast<std::size_t>(cellDims_.x * cellDims_.y * cellDims_.z);
    cellDir_.assign(cells, glm::vec3(0.0f));
    cellStamp_.assign(cells, 0);
  }
}

float TentReconstructor::outputAt(std::size_t i) const {
  const float sw = acc_[2 * i + 1];
  if (mode_ == Replacement::MotionVector && baseW_[i] > 0.0f) {
    if (sw > 0.0f) return wOld_ * baseV_[i] + wNew_ * (acc_[2 * i] / sw);
    return baseV_[i];
  }
  return sw > 0.0f ? acc_[2 * i] / sw : 0.0f;
}

float TentReconstructor::weightAt(std::size_t i) const {
  const float sw = acc_[2 * i + 1];
  if (mode_ == Replacement::MotionVector && baseW_[i] > 0.0f) return sw > 0.0f ? sw / wNew_ : baseW_[i];
  return sw;
}

Volume TentReconstructor::weights() const {
  Volume w;
  w.allocate(grid_, ScalarType::F32);
  const std::size_t n = acc_.size() / 2;
  for (std::size_t i = 0; i < n; ++i) storeF32(w.bytes.data(), i, weightAt(i));
  return w;
}



// The profiles of rows y0 - padRows .. y1 + padRows of img (zero outside
// y0..y1) into profiles_. Rows are independent, so any split of them among
// the threads gives the same bits.
void TentReconstructor::buildProfiles(const SliceImage& img, const KnotLattice& lat, int padRows) {
  const std::size_t stride = 6 * static_cast<std::size_t>(lat.periods());
  const int rows = img.y1 - img.y0 + 1;
  const std::size_t pad = static_cast<std::size_t>(padRows) * stride;
  profiles_.resize(static_cast<std::size_t>(rows) * stride + 2 * pad);
  std::fill_n(profiles_.data(), pad, 0.0f);
  std::fill_n(profiles_.data() + profiles_.size() - pad, pad, 0.0f);
  const int threads = std::min(threads_, rows);
#pragma omp parallel num_threads(threads) if (threads > 1)
  {
    ProfileRow row(lat, hl_);
    float* const first = profiles_.data() + pad;
#pragma omp for schedule(static)
    for (int r = 0; r < rows; ++r) row.build(img, img.y0 + r, first + static_cast<std::size_t>(r) * stride);
  }
}

// The slice's kernel, its profiles (into profiles_) and axial offsets (into rowOff_).
SliceKernel TentReconstructor::sliceKernel(const SlicePose& pose, const SliceImage& img) {
  // Every pixel row that can be within ha of a voxel (at most
  // floor(2 ha / syv) + 1 of them) is in its axial window.
  SliceKernel K{};
  K.lat = knotLattice(pose.sx, hl_, img.x0, img.x1);
  K.ha = ha_;
  K.syv = pose.syv;
  K.invSyv = 1.0 / pose.syv;
  K.eyu = pose.eyu;
  K.invHe = 1.0 / he_;
  K.invHaF = static_cast<float>(1.0 / ha_);
  K.y0 = img.y0;
  K.y1 = img.y1;
  K.rows = static_cast<int>(std::floor(2.0 * ha_ / pose.syv)) + 1;
  K.chunks = (K.rows + 3) / 4;
  // The window starts at most `rows` rows before y0 and reaches at most
  // 4 * chunks - 1 rows past y1.
  const int padRows = 4 * K.chunks;
  K.oy = img.y0 - padRows;
  // floor((V - ha) / syv) + 1 - oy, clamped to [y0 - rows, y1 + 1] - oy.
  K.firstBase = 1.0 - K.oy;
  K.firstLo = img.y0 - K.rows - K.oy;
  K.firstHi = img.y1 + 1 - K.oy;
  K.stride = 6 * static_cast<std::size_t>(K.lat.periods());
  buildProfiles(img, K.lat, padRows);
  K.prof = profiles_.data();
  rowOff_.assign(static_cast<std::size_t>(4 * K.chunks), std::numeric_limits<float>::infinity());
  for (int rr = 0; rr < K.rows; ++rr)
    rowOff_[static_cast<std::size_t>(rr)] = static_cast<float>(rr) * static_cast<float>(pose.syv);
  K.rowOff = rowOff_.data();
  return K;
}

template <class Sums, Along A, Replacement R>
void TentReconstructor::contributeRows(const Sums& sumsRef, const SliceFrame& sf, std::size_t first,
                                       std::size_t end, float tf) {
  Sums sums = sumsRef;  // this thread's own
  float* const acc = acc_.data();
  float* const out = outF32();
  float* const contrib = contrib_.data();
  const std::int64_t nx = grid_.dims.x, nxy = grid_.dims.x * grid_.dims.y;
  const Vec3 s = sf.step[0], sj = sf.step[1], sk = sf.step[2];
  const double invHe = 1.0 / he_;
  float cacheT = std::numeric_limits<float>::quiet_NaN(), cacheF = 1.0f;
  for (std::size_t q = first; q < end; ++q) {
    const std::size_t r = order_[q];
    // Rows a slice crosses are often short and a grid row apart: fetch the
    // voxels of a row a few rows ahead while this one computes.
    constexpr std::size_t kAhead = 6;
    if (q + kAhead < end) {
      const Row& ahead = rows_[order_[q + kAhead]];
      const std::int64_t l0 = ahead.j * nx + ahead.k * nxy;
      const auto firstV = static_cast<std::size_t>(l0 + ahead.i0);
      const auto lastV = static_cast<std::size_t>(l0 + ahead.i1);
      __builtin_prefetch(acc + 2 * firstV, 1);
      __builtin_prefetch(acc + 2 * lastV + 1, 1);
      __builtin_prefetch(out + firstV, 1);
      __builtin_prefetch(out + lastV, 1);
    }
    const Row& row = rows_[r];
    ChangedRange changed;
    const Vec3 b = sf.base + static_cast<double>(row.j) * sj + static_cast<double>(row.k) * sk;
    const std::int64_t lin0 = row.j * nx + row.k * nxy;
    float rowSw = 0.0f, rowSwv = 0.0f;
    if constexpr (A != Along::Any) sums.axial(b.y);  // s.y == 0: V is b.y all along the row
    if constexpr (A == Along::ConstUV) sums.inPlane(b.x, rowSw, rowSwv);
    for (std::int64_t i = row.i0; i <= row.i1; ++i) {
      const auto di = static_cast<double>(i);
      const double N = b.z + di * s.z;
      const double tn = 1.0 - std::abs(N) * invHe;
      float cw = 0.0f, cwv = 0.0f;
      if (tn > 0.0) {
        float sw = rowSw, swv = rowSwv;
        if constexpr (A != Along::ConstUV) {
          if constexpr (A == Along::Any) sums.axial(b.y + di * s.y);
          sums.inPlane(b.x + di * s.x, sw, swv);
        }
        const auto tnf = static_cast<float>(tn);
        cw = sw * tnf;
        cwv = swv * tnf;
      }
      const bool hit = cw > 0.0f;  // some selected pixel reaches the voxel
      if constexpr (R == Replacement::MotionVector) {
        // Stored: the cells to rebase are known only once the slice is summed.
        float* c = contrib + 2 * (row.offset + static_cast<std::size_t>(i - row.i0));
        c[0] = hit ? cw : 0.0f;
        c[1] = hit ? cwv : 0.0f;
      } else {
        if (hit && applyVoxel<R>(acc, out, static_cast<std::size_t>(lin0 + i), cw, cwv, tf, cacheT, cacheF))
          changed.add(i, out[lin0 + i]);
      }
    }
    rowChanged_[r] = changed;
  }
}

// The order the rows are visited in: rows_ (z outer, y inner), or y outer and
// z inner where a step in z moves a voxel's foot point less than half as far
// across the slice as a step in y (a slice facing z): consecutive rows then
// read nearly the same profiles, from cache. Each voxel's arithmetic is its
// own, so the order changes no bits.
void TentReconstructor::visitOrder(const SliceFrame& sf) {
  order_.resize(rows_.size());
  for (std::size_t r = 0; r < rows_.size(); ++r) order_[r] = r;
  auto across = [](const Vec3& step) { return std::hypot(step.x, step.y); };
  if (across(sf.step[2]) < 0.5 * across(sf.step[1]))
    std::sort(order_.begin(), order_.end(), [&](std::size_t a, std::size_t b) {
      return rows_[a].j != rows_[b].j ? rows_[a].j < rows_[b].j : rows_[a].k < rows_[b].k;
    });
}

void TentReconstructor::collectChanged(std::vector<RowRun>& runs) const {
  for (std::size_t r = 0; r < rows_.size(); ++r) {
    const ChangedRange& c = rowChanged_[r];
    if (c.lo <= c.hi)
      runs.push_back({static_cast<std::int32_t>(rows_[r].j), static_cast<std::int32_t>(rows_[r].k), c.lo, c.hi, c.max});
  }
}

template <class Sums, Along A>
void TentReconstructor::contribute(const Sums& sums, const SliceFrame& sf, float tf) {
  switch (mode_) {
    case Replacement::Accumulate:
      forRows([&](std::size_t a, std::size_t b) { contributeRows<Sums, A, Replacement::Accumulate>(sums, sf, a, b, tf); });
      break;
    case Replacement::Decay:
      forRows([&](std::size_t a, std::size_t b) { contributeRows<Sums, A, Replacement::Decay>(sums, sf, a, b, tf); });
      break;
    case Replacement::MotionVector:
      forRows([&](std::size_t a, std::size_t b) { contributeRows<Sums, A, Replacement::MotionVector>(sums, sf, a, b, tf); });
      break;
  }
}

// How V and U change along a grid row picks the loop (see Along).
template <class Sums>
void TentReconstructor::contributeAlong(const Sums& sums, const SliceFrame& sf, float tf) {
  const Vec3 sa = sf.step[0];
  if (sa.y != 0.0)
    contribute<Sums, Along::Any>(sums, sf, tf);
  else if (sa.x != 0.0)
    contribute<Sums, Along::ConstV>(sums, sf, tf);
  else
    contribute<Sums, Along::ConstUV>(sums, sf, tf);
}

void TentReconstructor::splat(const SlicePose& pose, const SliceImage& img, double timeS, const Vec3& dir,
                              DirtyRegion& dirty, std::vector<RowRun>& changed) {
  const Grid& g = grid_;
  // The pixel centres' extent in slice coordinates, and the kernel's support
  // around it: the open box lo < (U, V, N) < hi.
  double uLo = std::numeric_limits<double>::infinity(), uHi = -uLo;
  for (const int c : {img.x0, img.x1})
    for (const int r : {img.y0, img.y1}) {
      const double u = c * pose.sx + r * pose.eyu;
      uLo = std::min(uLo, u);
      uHi = std::max(uHi, u);
    }
  const double vLo = img.y0 * pose.syv, vHi = img.y1 * pose.syv;
  const Vec3 lo(uLo - hl_, vLo - ha_, -he_), hi(uHi + hl_, vHi + ha_, he_);

  // The same box for the dirty region, with a little slack for rounding.
  constexpr double kTiny = 1e-6, kPad = 1e-3;
  addOrientedSlab(dirty, pose.origin + uLo * pose.u + vLo * pose.v, std::max(uHi - uLo, kTiny) * pose.u,
                  std::max(vHi - vLo, kTiny) * pose.v, Vec3(hl_, ha_, he_) + Vec3(kPad));

  // Voxel index -> slice coordinates. Rows run along x, the contiguous axis,
  // even when the slice faces x and its rows are only a few voxels long: rows
  // along the axis most parallel to the slice would be longer, but their
  // voxels would sit a grid row or plane apart, and measured slower.
  SliceFrame sf;
  const Vec3 d0 = g.origin - pose.origin;
  sf.base = Vec3(glm::dot(d0, pose.u), glm::dot(d0, pose.v), glm::dot(d0, pose.n));
  for (int ax = 0; ax < 3; ++ax) sf.step[ax] = g.spacing[ax] * Vec3(pose.u[ax], pose.v[ax], pose.n[ax]);

  // Index bounds of the box, then one run of voxels per (j, k) row.
  Vec3 vmin(std::numeric_limits<double>::infinity()), vmax(-std::numeric_limits<double>::infinity());
  for (int a = 0; a < 8; ++a) {
    const Vec3 sc((a & 1) ? hi.x : lo.x, (a & 2) ? hi.y : lo.y, (a & 4) ? hi.z : lo.z);
    const Vec3 w = pose.origin + sc.x * pose.u + sc.y * pose.v + sc.z * pose.n;
    const Vec3 ijk = g.worldToVoxel(w);
    vmin = glm::min(vmin, ijk);
    vmax = glm::max(vmax, ijk);
  }
  auto indexRange = [&](int ax, std::int64_t& first, std::int64_t& last) {
    const auto n = static_cast<double>(g.dims[ax]);
    first = std::max<std::int64_t>(0, static_cast<std::int64_t>(std::clamp(std::floor(vmin[ax]), -1.0, n)));
    last = std::min<std::int64_t>(g.dims[ax] - 1, static_cast<std::int64_t>(std::clamp(std::ceil(vmax[ax]), -1.0, n)));
  };
  std::int64_t jLo, jHi, kLo, kHi, aLo, aHi;
  indexRange(1, jLo, jHi);
  indexRange(2, kLo, kHi);
  indexRange(0, aLo, aHi);
  // Windowed (setWindow): only the rows and voxels of reach(). A voxel's
  // arithmetic below is absolute (base + index * step), and a row's run is
  // found as before and then cut, so every voxel kept gets the same bits.
  const Box3& win = reach();
  jLo = std::max(jLo, win.lo.y);
  jHi = std::min(jHi, win.hi.y - 1);
  kLo = std::max(kLo, win.lo.z);
  kHi = std::min(kHi, win.hi.z - 1);
  const std::int64_t iLo = std::max(aLo, win.lo.x), iHi = std::min(aHi, win.hi.x - 1);
  const Vec3 sa = sf.step[0];
  const Vec3 invSa(std::abs(sa.x) < 1e-12 ? 0.0 : 1.0 / sa.x, std::abs(sa.y) < 1e-12 ? 0.0 : 1.0 / sa.y,
                   std::abs(sa.z) < 1e-12 ? 0.0 : 1.0 / sa.z);
  rows_.clear();
  std::size_t total = 0;
  for (std::int64_t k = kLo; k <= kHi; ++k)
    for (std::int64_t j = jLo; j <= jHi; ++j) {
      const Vec3 a = sf.base + static_cast<double>(j) * sf.step[1] + static_cast<double>(k) * sf.step[2];
      double ilo = static_cast<double>(aLo) - 1.0, ihi = static_cast<double>(aHi) + 1.0;
      clipInterval(a.x, sa.x, invSa.x, lo.x, hi.x, ilo, ihi);
      clipInterval(a.y, sa.y, invSa.y, lo.y, hi.y, ilo, ihi);
      clipInterval(a.z, sa.z, invSa.z, lo.z, hi.z, ilo, ihi);
      if (!(ilo < ihi)) continue;
      // ilo and ihi lie in [aLo - 1, aHi + 1] here.
      const std::int64_t i0 = std::max<std::int64_t>(iLo, floorInt(ilo) + 1);
      const std::int64_t i1 = std::min<std::int64_t>(iHi, -floorInt(-ihi) - 1);
      if (i0 > i1) continue;
      rows_.push_back({j, k, i0, i1, total});
      total += static_cast<std::size_t>(i1 - i0 + 1);
    }
  if (rows_.empty()) return;
  visitOrder(sf);

  const auto tf = static_cast<float>(timeS - t0_);
  if (mode_ == Replacement::MotionVector && contrib_.size() < 2 * total) contrib_.resize(2 * total);
  rowChanged_.resize(rows_.size());
  // An image whose y axis is perpendicular to its x axis (any rigid pose with
  // a pixel scale) has the same knots on every row.
  const bool sheared = std::abs(pose.eyu) * (img.y1 + 1) > 1e-9;
  const SliceKernel K = sliceKernel(pose, img);
  if (sheared)
    contribute<KnotSums<true>, Along::Any>(KnotSums<true>(K), sf, tf);
  else
    contributeAlong(KnotSums<false>(K), sf, tf);
  if (mode_ == Replacement::MotionVector) {
    rebaseCells(dir);
    applyStored(tf);
  }
  collectChanged(changed);
}

SlicePose TentReconstructor::checkPose(const std::string& what, const Mat4& imageToReference, double timeS) const {
  // A time in seconds, as PLUS writes them (from an epoch or the recording's
  // start): beyond 1e10 s (three centuries) it is a damaged field, and its
  // difference with the next frame's would not fit the decay's float times.
  if (!std::isfinite(timeS) || std::abs(timeS) > 1e10)
    throw InputError(fmt::format("{}: the timestamp {} s is not a time (finite, within 1e10 s)", what, timeS));
  const SlicePose pose = poseFromMatrix(imageToReference, what);
  // A kernel that spans more than this many pixels (each knot of a profile
  // sums as many, each voxel as many rows) is taken for a pose with the wrong
  // scale.
  constexpr auto kMaxWindow = static_cast<double>(kMaxWindowPixels);
  if (!(2.0 * hl_ / pose.sx <= kMaxWindow) || !(2.0 * ha_ / pose.syv <= kMaxWindow))
    throw InputError(fmt::format("{}: pixels of {:.3g} x {:.3g} mm are too small for the tent kernel "
                                 "({} x {} mm half-widths span more than {} pixels)",
                                 what, pose.sx, pose.syv, hl_, ha_, kMaxWindow));
  return pose;
}

void TentReconstructor::selectRuns(int width, int height) {
  if (width == runsWidth_ && height == runsHeight_) return;  // the selection depends on the frame size only
  runs_ = pixelRuns(width, height, settings_);
  runsWidth_ = width;
  runsHeight_ = height;
  // Their bounding box (the whole image when it is empty), for the geometry
  // below, which must not move with the pixels that happen to be rejected.
  runsBox_ = {width, height, -1, -1};
  for (const PixelRun& run : runs_)
    runsBox_ = {std::min(runsBox_.x, run.x0), std::min(runsBox_.y, run.y), std::max(runsBox_.z, run.x1),
                std::max(runsBox_.w, run.y)};
  if (runs_.empty()) runsBox_ = {0, 0, width - 1, height - 1};
}

bool TentReconstructor::stepMotion(const SlicePose& pose, double timeS, double& maxCornerMm) {
  if (mode_ == Replacement::Decay && hasPrev_ && !(timeS > prevTime_) && !saidTimeOrder_) {
    saidTimeOrder_ = true;
    spdlog::warn("recon: a frame's timestamp ({} s) does not come after the previous frame's ({} s); the decay "
                 "replacement counts time only forward (said once)",
                 timeS, prevTime_);
  }
  if (!hasT0_) {
    t0_ = timeS;
    hasT0_ = true;
  }
  // Corners of the clip rectangle and fan.
  const double cx0 = runsBox_.x, cy0 = runsBox_.y, cx1 = runsBox_.z, cy1 = runsBox_.w;
  const Vec3 centre = pose.pixel(0.5 * (cx0 + cx1), 0.5 * (cy0 + cy1));

  // A jump (or the first frame): no fill-in, and no direction of motion.
  bool jump = true;
  maxCornerMm = 0.0;
  if (hasPrev_) {
    for (const double c : {cx0, cx1})
      for (const double r : {cy0, cy1})
        maxCornerMm = std::max(maxCornerMm, glm::length(pose.pixel(c, r) - prevPose_.pixel(c, r)));
    const double angleDeg = rotationAngle(prevPose_, pose) * (180.0 / 3.14159265358979323846);
    jump = maxCornerMm > settings_.tent.fillInMaxGapMm || angleDeg > settings_.tent.fillInMaxAngleDeg;
  }
  if (jump) {
    dir_ = Vec3(0.0);
    anchor_ = centre;
  } else {
    const Vec3 d = centre - anchor_;
    const double len = glm::length(d);
    if (len >= 0.5 * he_) {
      dir_ = d / len;
      anchor_ = centre;
    }
  }
  return jump;
}

void TentReconstructor::endFrame(const SlicePose& pose, double timeS, bool pixelsKnown) {
  prevPose_ = pose;
  prevTime_ = timeS;
  hasPrev_ = true;
  prevPixels_ = pixelsKnown;
  lastAdvanced_ = !pixelsKnown;
  started_ = true;
}

InsertResult TentReconstructor::insert(const Frame& f, const Mat4& imageToReference, double timeS) {
  // Everything is checked before any state changes, so a refused frame leaves
  // the reconstruction as it was.
  const std::string what = fmt::format("frame {}", f.index);
  if (f.width <= 0 || f.height <= 0) throw InputError(what + ": the image is empty");
  if (f.pixels.size() != f.byteSize())
    throw InputError(fmt::format("{}: the pixel buffer holds {} bytes, but a {}x{} image needs {}", what,
                                 f.pixels.size(), f.width, f.height, f.byteSize()));
  const SlicePose pose = checkPose(what, imageToReference, timeS);

  selectRuns(f.width, f.height);
  selectPixels(f, runs_, settings_.pixelRejectionThreshold, cur_);
  InsertResult res;
  // 8-voxel bricks: the slab a slice changes is about 2 he thick, and coarser
  // bricks would make shading and re-sampling (which follow them) do 2-3x the work.
  res.dirty = DirtyRegion(grid_, 8);
  res.pixelsInserted = cur_.selected;
  double maxCornerMm = 0.0;
  const bool jump = stepMotion(pose, timeS, maxCornerMm);

  // Without the previous frame's pixels (it went to advance() and
  // restorePrevious() did not follow) there is nothing to fill in from.
  if (settings_.tent.fillIn && !jump && prevPixels_ && cur_.selected > 0 && prev_.selected > 0 &&
      prev_.width == cur_.width && prev_.height == cur_.height) {
    const int n = fillInCount(maxCornerMm, he_);
    // Pixels kept in both frames lie in the intersection of their boxes.
    const int x0 = std::max(prev_.x0, cur_.x0), x1 = std::min(prev_.x1, cur_.x1);
    const int y0 = std::max(prev_.y0, cur_.y0), y1 = std::min(prev_.y1, cur_.y1);
    for (int s = 1; s <= n && x0 <= x1 && y0 <= y1; ++s) {
      const double t = static_cast<double>(s) / (n + 1);
      if (!blendSlices(prev_, cur_, {x0, y0, x1, y1}, t, mid_)) continue;
      splat(interpolatePose(prevPose_, pose, t), mid_, prevTime_ + (timeS - prevTime_) * t, dir_, res.dirty,
            res.changedRuns);
      ++res.fillInSlices;
    }
  }

  if (cur_.selected > 0) splat(pose, cur_, timeS, dir_, res.dirty, res.changedRuns);
  std::swap(prev_, cur_);
  endFrame(pose, timeS, true);
  if (windowed()) {
    // Only the bricks that overlap the window: the rest of the slab was not
    // written, and its bricks would only make later stages work for nothing.
    DirtyRegion clipped(grid_, res.dirty.brickSize());
    const Index3 bd = clipped.brickDims();
    for (const std::uint32_t b : res.dirty.bricks())
      if (!res.dirty.brickBox(b).intersect(window()).empty()) {
        const std::int64_t id = b;
        clipped.addBrick(id % bd.x, (id / bd.x) % bd.y, id / (bd.x * bd.y));
      }
    res.dirty = std::move(clipped);
  }
  return res;
}

void TentReconstructor::setWindow(const Box3& window) {
  PP5_CHECK(!started_);  // the voxels outside the window would already hold data, and the contract is per stream
  Reconstructor::setWindow(window);
}

InsertResult TentReconstructor::advance(int width, int height, const Mat4& imageToReference, double timeS) {
  // The same checks as insert() (less the pixels'), before any state changes.
  const std::string what = fmt::format("frame at t = {} s", timeS);
  if (width <= 0 || height <= 0) throw InputError(what + ": the image is empty");
  const SlicePose pose = checkPose(what, imageToReference, timeS);
  selectRuns(width, height);
  double maxCornerMm = 0.0;
  (void)stepMotion(pose, timeS, maxCornerMm);
  endFrame(pose, timeS, false);
  InsertResult res;
  res.dirty = DirtyRegion(grid_, 8);
  return res;
}

void TentReconstructor::restorePrevious(const Frame& f) {
  PP5_CHECK(lastAdvanced_);  // only the frame just advanced can be given back
  PP5_CHECK_EQ(f.width, runsWidth_);  // runs_ are the advanced frame's
  PP5_CHECK_EQ(f.height, runsHeight_);
  if (f.pixels.size() != f.byteSize())
    throw InputError(fmt::format("frame {}: the pixel buffer holds {} bytes, but a {}x{} image needs {}", f.index,
                                 f.pixels.size(), f.width, f.height, f.byteSize()));
  // As insert() would have selected them; they are the next fill-in's prev_.
  selectPixels(f, runs_, settings_.pixelRejectionThreshold, prev_);
  prevPixels_ = true;
  lastAdvanced_ = false;
}

}  // namespace tent

using tent::TentReconstructor;

std::uint64_t tentBytesPerVoxel(const ReconSettings& s) {
  std::uint64_t b = 12;  // output, sum(w*v), sum(w): F32 each
  switch (s.tent.replacement) {
    case Replacement::Accumulate: break;
    case Replacement::Decay: b += 4; break;  // time of the last update
    case Replacement::MotionVector: {
      // base value and weight, plus a 16-byte cell per motionVectorBrick^3 voxels
      const std::uint64_t c = static_cast<std::uint64_t>(std::max(1, s.tent.motionVectorBrick));
      b += 8 + (16 + c * c * c - 1) / (c * c * c);
      break;
    }
  }
  return b;
}

std::unique_ptr<Reconstructor> makeTentReconstructor(const Grid& g, const ReconSettings& s) {
  return std::make_unique<TentReconstructor>(g, s);
}

}  // namespace pp5::gp
