// A part of reconstruction/pixel_kernels.cpp, included there inside its unnamed
// namespace: the pixel kernels are one translation unit, so that they compile
// exactly as they did in one file (the compiler inlines a helper by how many
// calls it sees), cut into the walk they share and one file per method to
// keep each file short. Not a header: it includes nothing and stands alone.
// ---------------------------------------------------------------------------
// Nearest neighbour: the pixels of one segment are one voxel's, so the
// segment's update is gathered in registers and the voxel written once.

template <class Pix, Compounding C>
void nearestFloat(const Job& job, FloatCell* cells, const Slab& slab, bool split, SlabOut& out) {
  const Bounds bd(job, slab);
  const std::int64_t sy = job.sy, sz = job.sz;
  const int rej = job.rejectBelow;
  std::int64_t off[3];
  std::uint64_t range[3];
  for (int a = 0; a < 3; ++a) {
    off[a] = kOffsetI + bd.lo[a];
    range[a] = static_cast<std::uint64_t>(bd.hi[a] - bd.lo[a]);
  }
  std::uint64_t inserted = 0;
  for (const PixelRun& r : *job.runs) {
    const Pix* row = rowPtr<Pix>(job, r.y);
    FloatStep st[3];
    for (int a = 0; a < 3; ++a)
      st[a] = FloatStep(job.map.O[a] + double(r.y) * job.map.Y[a] + (0.5 + kOffset), job.map.X[a]);
    int ia = r.x0, ib = r.x1;
    if (split) {
      const int a = slab.axis;
      columnRange(st[a].b, st[a].X, kOffset + double(bd.lo[a]), kOffset + double(bd.hi[a]), r.x0, r.x1, ia, ib);
    }
    if (ia > ib) continue;
    RowWrites wr(job, out, static_cast<std::size_t>(ib - ia + 1));  // a voxel per segment at most
    // MEAN: a segment's sum and count from prefix sums, without a loop whose
    // length the branch predictor cannot guess.
    // (pre[k - ia]: sum of the pixels ia .. k-1)
    std::uint64_t* pre = out.prefix.data();
    std::uint32_t* pre32 = out.prefix32.data();  // 8-bit pixels, no rejection
    std::uint32_t* cnt = out.count.data();
    constexpr bool kBytes = sizeof(Pix) == 1;
    if constexpr (C == Compounding::Mean) {
      std::uint64_t sum = 0;
      pre[0] = 0;
      const int len = ib - ia + 1;
      const Pix* px = row + ia;
      if (kBytes && rej <= 0) {
        prefixSumsU8(reinterpret_cast<const std::uint8_t*>(px), len, pre32);
      } else if (rej <= 0) {
        for (int k = 0; k < len; ++k) pre[k + 1] = sum += px[k];
      } else {
        std::uint32_t n = 0;
        cnt[0] = 0;
        for (int k = 0; k < len; ++k) {
          const int p = px[k];
          const bool ok = p >= rej;
          pre[k + 1] = sum += ok ? static_cast<std::uint64_t>(p) : 0u;
          cnt[k + 1] = n += ok;
        }
      }
    }
    walkRunFloat(st, ia, ib, out.marks.data(), [&](int i, int e, std::int64_t mx, std::int64_t my, std::int64_t mz) {
      const std::int64_t ux = mx - off[0], uy = my - off[1], uz = mz - off[2];
      if ((static_cast<std::uint64_t>(ux) >= range[0]) | (static_cast<std::uint64_t>(uy) >= range[1]) |
          (static_cast<std::uint64_t>(uz) >= range[2]))
        return;
      std::uint32_t n = 0;
      float value = 0.0f;
      if constexpr (C == Compounding::Mean) {
        n = rej <= 0 ? static_cast<std::uint32_t>(e - i) : cnt[e - ia] - cnt[i - ia];
        // exact below 2^24
        value = kBytes && rej <= 0 ? static_cast<float>(pre32[e - ia] - pre32[i - ia])
                                   : static_cast<float>(pre[e - ia] - pre[i - ia]);
      } else {
        int v = -1;
        for (int k = i; k < e; ++k) {
          const int p = row[k];
          if (p < rej) continue;
          v = C == Compounding::Latest ? p : std::max(v, p);
          ++n;
        }
        value = static_cast<float>(v);
      }
      if (n == 0) return;
      const std::int64_t x = bd.lo[0] + ux, y = bd.lo[1] + uy, z = bd.lo[2] + uz;
      const std::int64_t idx = x + y * sy + z * sz;
      FloatCell& c = cells[idx];
      if constexpr (C == Compounding::Mean) c.s += value;
      if constexpr (C == Compounding::Latest) c.s = value;
      if constexpr (C == Compounding::Maximum) c.s = std::max(c.s, value);
      c.w += static_cast<float>(n);
      wr.add(idx, x, y, z);
      inserted += n;
    });
  }
  out.pixels += inserted;
}

// PLUS's FULL-optimisation nearest neighbour (§3.3, §3.6): voxel floor(v + 1/2)
// of the fixed position, PLUS's compounding applied pixel by pixel (in
// registers along a segment).
template <Compounding C>
void nearestPlus(const Job& job, PlusCell* cells, const Slab& slab, bool split, SlabOut& out) {
  using namespace plusmath;
  const Bounds bd(job, slab);
  const std::int64_t sy = job.sy, sz = job.sz;
  const int rej = job.rejectBelow;
  std::uint64_t inserted = 0;
  for (const PixelRun& r : *job.runs) {
    const std::uint8_t* row = rowPtr<std::uint8_t>(job, r.y);
    FixedAxis ax[3];
    for (int a = 0; a < 3; ++a) ax[a] = FixedAxis(job.fmap.O[a] + std::int64_t{r.y} * job.fmap.Y[a] + kHalf, job.fmap.X[a]);
    int ia = r.x0, ib = r.x1;
    if (split) {
      const int a = slab.axis;
      columnRange(double(ax[a].b) / kOne, double(ax[a].X) / kOne, double(bd.lo[a]), double(bd.hi[a]), r.x0, r.x1, ia,
                  ib);
    }
    if (ia > ib) continue;
    RowWrites wr(job, out, static_cast<std::size_t>(ib - ia + 1));  // a voxel per segment at most
    walkRun(ax, ia, ib, [&](int i, int e, const std::int64_t* q) {
      const std::int64_t x = q[0], y = q[1], z = q[2];
      if (!(bd.owns(0, x) && bd.owns(1, y) && bd.owns(2, z))) return;
      const std::int64_t idx = x + y * sy + z * sz;
      std::uint32_t v = cells[idx].v, acc = cells[idx].a, n = 0;
      for (int k = i; k < e; ++k) {
        const std::uint32_t in = row[k];
        if (static_cast<int>(in) < rej) continue;
        ++n;
        if constexpr (C == Compounding::Mean) {
          if (acc <= 65279u) {
            // PLUS: v = (in*256 + v*acc) / (acc + 256), an integer division
            // that truncates at every step. acc is a multiple of 256 here (the
            // k - 1 earlier hits), so this is (in + v*(k-1)) / k.
            const std::uint32_t hits = (acc >> 8) + 1u;
            v = plusmath::divSmall(in + v * (hits - 1u), hits);
            acc += 256u;
          } else {
            // Saturated accumulator: PLUS's recursive filter, truncated.
            v = static_cast<std::uint32_t>(in * (1.0 / 256.0) + v * (255.0 / 256.0));
          }
        }
        if constexpr (C == Compounding::Latest) {
          v = in;
          acc = 256u;
        }
        if constexpr (C == Compounding::Maximum) {
          v = std::max(v, in);
          acc = 256u;
        }
      }
      if (n == 0) return;
      cells[idx].v = static_cast<std::uint8_t>(v);
      cells[idx].a = static_cast<std::uint16_t>(acc);
      wr.add(idx, x, y, z);
      inserted += n;
    });
  }
  out.pixels += inserted;
}

