// A part of reconstruction/pixel_kernels.cpp, included there inside its unnamed
// namespace: the pixel kernels are one translation unit, so that they compile
// exactly as they did in one file (the compiler inlines a helper by how many
// calls it sees), cut into the walk they share and one file per method to
// keep each file short. Not a header: it includes nothing and stands alone.
// ---------------------------------------------------------------------------
// Trilinear. Consecutive pixels with the same lower corner n0 form a group
// (float: a walker segment): their contributions to the eight corners are
// gathered in registers and each corner is written once per group (float), or
// the corners' PLUS state is carried in registers through the group (plus).
// As for nearest neighbour the groups do not depend on the slab cut.

using simd::F4;
using simd::I4;

// Float: corner k = 4*bx + 2*by + bz; lanes 0..3 of the "lo" vectors are
// bx = 0 (by, bz = 00, 01, 10, 11), of the "hi" vectors bx = 1.
template <class Pix, Compounding C>
void trilinearFloat(const Job& job, FloatCell* cells, const Slab& slab, bool split, SlabOut& out) {
  const Bounds bd(job, slab);
  const int sa = slab.axis;
  const std::int64_t sy = job.sy, sz = job.sz;
  const int rej = job.rejectBelow;
  const double X0 = job.map.X[0], X1 = job.map.X[1], X2 = job.map.X[2];
  const float x0f = static_cast<float>(X0), x1f = static_cast<float>(X1), x2f = static_cast<float>(X2);
  // A segment can reach the thread's voxels only if n0 is in [lo-1, hi-1] on every axis.
  std::int64_t off[3];
  std::uint64_t range[3];
  for (int a = 0; a < 3; ++a) {
    off[a] = kOffsetI + bd.lo[a] - 1;
    range[a] = static_cast<std::uint64_t>(bd.hi[a] - bd.lo[a] + 1);
  }
  std::uint64_t inserted = 0;
  const F4 eighth = {kMinWeightFloat, kMinWeightFloat, kMinWeightFloat, kMinWeightFloat};
  const F4 zero = {0, 0, 0, 0};

  for (const PixelRun& r : *job.runs) {
    const Pix* row = rowPtr<Pix>(job, r.y);
    FloatStep st[3];
    for (int a = 0; a < 3; ++a) st[a] = FloatStep(job.map.O[a] + double(r.y) * job.map.Y[a] + kOffset, job.map.X[a]);
    const double b0 = st[0].b, b1 = st[1].b, b2 = st[2].b;
    int ia = r.x0, ib = r.x1;
    if (split)
      columnRange(st[sa].b, st[sa].X, kOffset + double(bd.lo[sa]) - 1.0, kOffset + double(bd.hi[sa]), r.x0, r.x1, ia,
                  ib);
    if (ia > ib) continue;
    RowWrites wr(job, out, 8 * static_cast<std::size_t>(ib - ia + 1));  // eight corners per segment at most
    walkRunFloat(st, ia, ib, out.marks.data(), [&](int i, int e, std::int64_t mx, std::int64_t my, std::int64_t mz) {
      if ((static_cast<std::uint64_t>(mx - off[0]) >= range[0]) | (static_cast<std::uint64_t>(my - off[1]) >= range[1]) |
          (static_cast<std::uint64_t>(mz - off[2]) >= range[2]))
        return;
      // Corner k = 4*bx + 2*by + bz; lanes 0..3 of the "lo" vectors hold
      // bx = 0 (by bz = 00, 01, 10, 11), the "hi" vectors bx = 1. MEAN keeps
      // weighted sums, LATEST / MAXIMUM values.
      F4 slo = zero, shi = zero, wlo = zero, whi = zero;
      // The fractions at the segment's first pixel, from the row in double
      // (the segment decides n0; clamped against rounding), then stepped in
      // float from pixel to pixel: y and z as the vectors (1-fy, 1-fy, fy, fy)
      // and (1-fz, fz, 1-fz, fz), so that each pixel's eight weights take
      // three products. The steps' rounding (about 1e-7 over a segment) is
      // clamped away at zero.
      const double di = i;
      const float f0 = static_cast<float>(std::min(std::max(b0 + di * X0 - double(mx), 0.0), 1.0));
      const float f1 = static_cast<float>(std::min(std::max(b1 + di * X1 - double(my), 0.0), 1.0));
      const float f2 = static_cast<float>(std::min(std::max(b2 + di * X2 - double(mz), 0.0), 1.0));
      F4 Y = {1.0f - f1, 1.0f - f1, f1, f1}, Z = {1.0f - f2, f2, 1.0f - f2, f2};
      F4 XL = zero + (1.0f - f0), XH = zero + f0;
      const F4 dY = {-x1f, -x1f, x1f, x1f}, dZ = {-x2f, x2f, -x2f, x2f}, dX = zero + x0f;
      std::uint32_t n = 0;
      for (int k = i; k < e; ++k) {
        const int inI = row[k];
        const F4 yz = Y * Z;
        F4 lo = yz * XL, hi = yz * XH;
        Y += dY;
        Z += dZ;
        XL -= dX;
        XH += dX;
        if (inI < rej) continue;
        ++n;
        lo = lo > zero ? lo : zero;
        hi = hi > zero ? hi : zero;
        const float in = static_cast<float>(inI);
        if constexpr (C == Compounding::Mean) {
          slo += lo * in;
          shi += hi * in;
          wlo += lo;
          whi += hi;
        } else {
          // Only where the weight is at least 1/8 (PLUS's rule).
          const I4 mlo = lo >= eighth, mhi = hi >= eighth;
          const F4 vin = {in, in, in, in};
          if constexpr (C == Compounding::Latest) {
            slo = mlo ? vin : slo;
            shi = mhi ? vin : shi;
          } else {
            slo = mlo ? (slo > vin ? slo : vin) : slo;
            shi = mhi ? (shi > vin ? shi : vin) : shi;
          }
          wlo += mlo ? lo : zero;
          whi += mhi ? hi : zero;
        }
      }
      if (n == 0) return;
      const std::int64_t c0 = mx - kOffsetI, c1 = my - kOffsetI, c2 = mz - kOffsetI;
      if (c0 >= bd.lo[0] && c0 + 1 < bd.hi[0] && c1 >= bd.lo[1] && c1 + 1 < bd.hi[1] && c2 >= bd.lo[2] &&
          c2 + 1 < bd.hi[2]) {
        // All eight corners are the thread's (the common case).
        const std::int64_t idx = c0 + c1 * sy + c2 * sz;
        const std::int64_t offs[8] = {0, sz, sy, sy + sz, 1, 1 + sz, 1 + sy, 1 + sy + sz};
        const std::int64_t bxs[2] = {wr.bx(c0), wr.bx(c0 + 1)}, bys[2] = {wr.by(c1), wr.by(c1 + 1)},
                           bzs[2] = {wr.bz(c2), wr.bz(c2 + 1)};
        for (int k = 0; k < 8; ++k) {
          const int lane = k & 3;
          const float w = k & 4 ? whi[lane] : wlo[lane];
          const float v = k & 4 ? shi[lane] : slo[lane];
          FloatCell& cell = cells[idx + offs[k]];
          if constexpr (C == Compounding::Mean) {
            cell.s += v;  // adding a zero weight changes nothing
            cell.w += w;
          } else if (w > 0.0f) {
            cell.s = C == Compounding::Latest ? v : std::max(cell.s, v);
            cell.w += w;
          }
          wr.add(idx + offs[k], bxs[k >> 2] + bys[(k >> 1) & 1] + bzs[k & 1]);
        }
        if (bd.owns(sa, sa == 0 ? c0 : sa == 1 ? c1 : c2)) inserted += n;
        return;
      }
      for (int k = 0; k < 8; ++k) {
        const int bx = k >> 2, by = (k >> 1) & 1, bz = k & 1;
        const std::int64_t x = c0 + bx, y = c1 + by, z = c2 + bz;
        if (!bd.owns(0, x) || !bd.owns(1, y) || !bd.owns(2, z)) continue;
        const int lane = k & 3;
        const float w = bx ? whi[lane] : wlo[lane];
        if (!(w > 0.0f)) continue;
        const float s = bx ? shi[lane] : slo[lane];
        const std::int64_t idx = x + y * sy + z * sz;
        FloatCell& cell = cells[idx];
        if constexpr (C == Compounding::Mean) cell.s += s;
        if constexpr (C == Compounding::Latest) cell.s = s;
        if constexpr (C == Compounding::Maximum) cell.s = std::max(cell.s, s);
        cell.w += w;
        wr.add(idx, x, y, z);
      }
      // Pixels that reach the grid, counted by the owner of their lowest layer inside it.
      const std::int64_t cs = sa == 0 ? c0 : sa == 1 ? c1 : c2;
      if (bd.owns(sa, std::max<std::int64_t>(cs, 0))) inserted += n;
    });
  }
  out.pixels += inserted;
}

// PLUS's FULL-optimisation trilinear splat (§4): fixed-point weights, the
// pixel dropped unless all eight corners are inside the grid, corners of
// weight 0 skipped. PLUS visits corners k = 7..0, but corners of non-zero
// weight are distinct voxels, so their order changes nothing.
template <Compounding C>
void trilinearPlus(const Job& job, PlusCell* cells, const Slab& slab, bool split, SlabOut& out) {
  using namespace plusmath;
  const Bounds bd(job, slab);
  const int sa = slab.axis;
  const std::int64_t sy = job.sy, sz = job.sz;
  const std::int64_t X0 = job.fmap.X[0], X1 = job.fmap.X[1], X2 = job.fmap.X[2];
  const std::uint64_t E[3] = {static_cast<std::uint64_t>(job.dims.x), static_cast<std::uint64_t>(job.dims.y),
                              static_cast<std::uint64_t>(job.dims.z)};
  std::uint64_t inserted = 0;
  for (const PixelRun& r : *job.runs) {
    const std::uint8_t* row = rowPtr<std::uint8_t>(job, r.y);
    std::int64_t b[3];
    for (int a = 0; a < 3; ++a) b[a] = job.fmap.O[a] + std::int64_t{r.y} * job.fmap.Y[a];
    int ia = r.x0, ib = r.x1;
    if (split)
      columnRange(double(b[sa]) / kOne, double(job.fmap.X[sa]) / kOne, double(bd.lo[sa]) - 1.0, double(bd.hi[sa]),
                  r.x0, r.x1, ia, ib);
    if (ia > ib) continue;
    RowWrites wr(job, out, 8 * static_cast<std::size_t>(ib - ia + 1));  // a group per pixel at most

    // The group: lower corner c, and per corner the PLUS state in registers.
    std::int64_t cur = -1;
    std::int64_t c[3] = {0, 0, 0};
    std::int32_t v[8], acc[8];
    std::uint32_t valid = 0, modified = 0;
    auto flush = [&] {
      for (int k = 0; k < 8; ++k) {
        if (!((valid & modified) >> k & 1u)) continue;
        const std::int64_t x = c[0] + (k >> 2), y = c[1] + ((k >> 1) & 1), z = c[2] + (k & 1);
        const std::int64_t idx = x + y * sy + z * sz;
        cells[idx].v = static_cast<std::uint8_t>(v[k]);
        cells[idx].a = static_cast<std::uint16_t>(acc[k]);
        wr.add(idx, x, y, z);
      }
    };
    for (int i = ia; i <= ib; ++i) {
      const std::int32_t in = row[i];
      if (in < job.rejectBelow) continue;
      const std::int64_t P[3] = {b[0] + i * X0, b[1] + i * X1, b[2] + i * X2};
      std::int64_t n0[3];
      std::int32_t f[3];
      bool inside = true;
      for (int a = 0; a < 3; ++a) {
        n0[a] = P[a] >> kFracBits;
        f[a] = static_cast<std::int32_t>(P[a] - (n0[a] << kFracBits));
        const std::int64_t n1 = n0[a] + (f[a] != 0);
        // All or nothing against the whole grid (unsigned: a negative n0 fails too).
        inside &= (static_cast<std::uint64_t>(n0[a]) < E[a]) & (static_cast<std::uint64_t>(n1) < E[a]);
      }
      if (!inside) continue;
      if (!bd.owns(sa, n0[sa]) && !bd.owns(sa, n0[sa] + 1)) continue;
      const std::int64_t key = n0[0] + n0[1] * sy + n0[2] * sz;
      if (key != cur) {
        if (cur >= 0) flush();
        cur = key;
        c[0] = n0[0];
        c[1] = n0[1];
        c[2] = n0[2];
        valid = modified = 0;
        for (int k = 0; k < 8; ++k) {
          const std::int64_t x = c[0] + (k >> 2), y = c[1] + ((k >> 1) & 1), z = c[2] + (k & 1);
          // A corner outside the grid only ever gets weight 0 (its axis has f = 0).
          if (bd.owns(0, x) && bd.owns(1, y) && bd.owns(2, z)) {
            const PlusCell& cell = cells[x + y * sy + z * sz];
            v[k] = cell.v;
            acc[k] = cell.a;
            valid |= 1u << k;
          } else {
            v[k] = acc[k] = 0;
          }
        }
      }
      if (bd.owns(sa, n0[sa])) ++inserted;
      const std::int32_t rx = kOne - f[0], ry = kOne - f[1], rz = kOne - f[2];
      const std::int32_t ryrz = mul(ry, rz), ryfz = mul(ry, f[2]), fyrz = mul(f[1], rz), fyfz = mul(f[1], f[2]);
      const std::int32_t w[8] = {mul(rx, ryrz),   mul(rx, ryfz),   mul(rx, fyrz),   mul(rx, fyfz),
                                 mul(f[0], ryrz), mul(f[0], ryfz), mul(f[0], fyrz), mul(f[0], fyfz)};
#pragma GCC unroll 8
      for (int k = 7; k >= 0; --k) {
        const std::int32_t wk = w[k];
        if (wk == 0) continue;
        // PLUS sets the accumulator to round((w + acc/256) * 256), capped at
        // 65535 (LATEST / MAXIMUM: round(w * 256)); acc/256 is exact in
        // fixed point, so that is acc + round(w / 64).
        const std::int32_t dacc = (wk + 32) >> 6;
        if constexpr (C == Compounding::Mean) {
          const std::int32_t rr = acc[k] * 64;  // acc / 256 as fixed, exact
          // The fixed division: the quotient rounded to double, then to 2^-14.
          v[k] = roundToInt(div(wk * in + rr * v[k], wk + rr));
          acc[k] = std::min(acc[k] + dacc, 65535);
        } else {
          const bool set = C == Compounding::Latest ? wk >= kMinWeightFixed : (wk >= kMinWeightFixed && in > v[k]);
          if (!set) continue;
          v[k] = in;
          acc[k] = dacc;  // replaced, not added to
        }
        modified |= 1u << k;
      }
    }
    if (cur >= 0) flush();
  }
  out.pixels += inserted;
}

