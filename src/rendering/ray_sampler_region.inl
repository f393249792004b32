// A part of rendering/ray_sampler.cpp, included there where it stood: sampling the
// lattice points in a D-buffer's intervals, what a frame's update
// re-samples. One translation unit with the rest of the sampler, so that it
// compiles exactly as it did in one file (the compiler inlines the walk's
// helpers by how many calls it sees); a file of its own to keep each short.
// Not a header: it includes nothing and stands alone.
void sampleRegion(const ShadeBuffer& shade, const SampleLattice& lattice, const DBuffer& dbuffer,
                  const RenderSettings& settings, SampleSink& sink, const EmptySpaceMap* space,
                  const SamplerOptions& options, const EmptySpaceMap* before, CellMarks changedCells) {
  checkSameGrid(shade.grid(), lattice.grid());
  PP5_CHECK(!before || space);
  if (before) {
    checkSameGrid(before->grid(), lattice.grid());
    PP5_CHECK(before->brickDims() == space->brickDims());
  }
  const std::uint8_t* distBefore = before ? before->distances() : nullptr;
  PP5_CHECK_EQ(dbuffer.width(), lattice.width());
  PP5_CHECK_EQ(dbuffer.height(), lattice.height());
  PP5_CHECK_GT(options.batchSamples, std::size_t{0});
  if (space) checkSameGrid(space->grid(), lattice.grid());
  const Interpolator interp(shade);
  const float e = exponentOf(lattice, settings);
  PP5_CHECK(!space || space->hasCellBits());
  const std::uint8_t* dist = space ? space->distances() : nullptr;
  const std::uint64_t* cells = space ? space->cellBits() : nullptr;
  const Index3 bd = space ? space->brickDims() : Index3(0);
  const int W = lattice.width(), H = lattice.height();
  const TileGrid tiles(W, H, options.tileSize);
  const TileSelection selection(tiles, options.workTiles);
  std::optional<OwnedCells> owned;
  if (options.ownedCells) owned.emplace(*options.ownedCells, lattice.grid().dims - Index3(1));
  if (owned && owned->empty()) return;

  // The touched pixels of the selected tiles, by tile (a counting sort keeps
  // each tile's pixels in the D-buffer's ascending order).
  const auto touched = dbuffer.touched();
  // Each touched pixel's tile, without a division per pixel: the pixels are
  // ascending, so the row advances with them, and a column table gives the
  // tile column.
  std::vector<std::uint32_t> tileOf(touched.size());
  {
    std::vector<std::uint32_t> tileColumn(static_cast<std::size_t>(W));
    for (int x = 0; x < W; ++x) tileColumn[static_cast<std::size_t>(x)] = static_cast<std::uint32_t>(x / tiles.size);
    const auto w = static_cast<std::uint32_t>(W);
    std::uint32_t y = 0, rowStart = 0;
    for (std::size_t i = 0; i < touched.size(); ++i) {
      const std::uint32_t p = touched[i];
      PP5_CHECK(i == 0 || p > touched[i - 1]);
      while (p - rowStart >= w) {
        ++y;
        rowStart += w;
      }
      tileOf[i] = (y / static_cast<std::uint32_t>(tiles.size)) * static_cast<std::uint32_t>(tiles.nx) +
                  tileColumn[p - rowStart];
    }
  }
  const std::uint8_t* mask = selection.all ? nullptr : options.workTiles.data();
  std::vector<std::uint32_t> start(tiles.count() + 1, 0);
  for (std::size_t i = 0; i < touched.size(); ++i) {
    const std::uint32_t t = tileOf[i];
    if (!mask || mask[t] != 0) ++start[t + 1];
  }
  std::vector<std::uint32_t> work;
  for (std::uint32_t t = 0; t < tiles.count(); ++t) {
    if (start[t + 1] > 0) work.push_back(t);
    start[t + 1] += start[t];
  }
  std::vector<std::uint32_t> order(start.back());
  {
    std::vector<std::uint32_t> pos(start.begin(), start.end() - 1);
    for (std::size_t i = 0; i < touched.size(); ++i) {
      const std::uint32_t t = tileOf[i];
      if (!mask || mask[t] != 0) order[pos[t]++] = touched[i];
    }
  }
  const double invStep = 1.0 / lattice.step();
  // The D-buffer has the touched pixels' perspective rays; the same camera's
  // are the lattice's, bit for bit.
  const Vec3* dirs = dbuffer.rays().camera() == lattice.camera() ? dbuffer.touchedDirs() : nullptr;
  const Vec3 eye = lattice.camera().eye;
  const int nt = std::max(1, std::min<int>(resolveThreads(settings.threads), static_cast<int>(work.size())));

#pragma omp parallel num_threads(nt)
  {
    Batcher out(sink, omp_get_thread_num(), options.batchSamples);
    RayStage stage(lattice.maxSamples(), e, compositesGreyValues(settings.compositing.front()));
    const OwnedCells* const mine = owned ? &*owned : nullptr;  // this thread's copy
#pragma omp for schedule(dynamic, 1)
    for (std::int64_t w = 0; w < static_cast<std::int64_t>(work.size()); ++w) {
      const std::uint32_t t = work[static_cast<std::size_t>(w)];
      out.startTile(t);
      for (std::uint32_t i = start[t]; i < start[t + 1]; ++i) {
        const std::uint32_t pixel = order[i];
        const std::int64_t n = lattice.count(pixel);
        if (n == 0) continue;
        const VoxelRay vr = dirs ? lattice.voxelRay(pixel, Ray{eye, dirs[pixel]}) : lattice.voxelRay(pixel);
        // The ray's owned samples, [own0, own1] (all of them without ownedCells).
        std::int64_t own0 = 0, own1 = n - 1;
        if (mine) {
          double kIn = 0.0, kOut = static_cast<double>(n - 1);
          for (int a = 0; a < 3; ++a) {
            const double b0 = vr.base[a], dl = vr.delta[a];
            if (dl == 0.0) {
              if (b0 < mine->lo(a) || b0 > mine->hi(a)) kOut = -1.0;
              continue;
            }
            const double inv = 1.0 / dl;
            const double ta = (mine->lo(a) - b0) * inv, tb = (mine->hi(a) - b0) * inv;
            kIn = std::max(kIn, std::min(ta, tb));
            kOut = std::min(kOut, std::max(ta, tb));
          }
          if (!(kOut >= kIn)) continue;
          own0 = static_cast<std::int64_t>(std::ceil(kIn));
          own1 = static_cast<std::int64_t>(kOut);  // floor: kOut >= 0
          if (!mine->exact(interp, vr, own0, own1)) continue;
        }
        const double t0 = lattice.t0(pixel);
        std::int64_t done = -1;  // spans are disjoint, but rounding must not repeat a sample
        Cells4 c, next;
        Interpolator::Voxels vox{};
        std::int64_t loaded = -1;
        for (const DBuffer::Span& sp : dbuffer.spans(pixel)) {
          const std::int64_t k0 = std::max<std::int64_t>(
              done + 1, static_cast<std::int64_t>(std::clamp(std::ceil((sp.tIn - t0) * invStep), 0.0, 65536.0)));
          const double hiK = std::floor((sp.tOut - t0) * invStep);
          if (hiK < 0.0) continue;
          const std::int64_t k1 = std::min<std::int64_t>(n - 1, static_cast<std::int64_t>(std::min(hiK, 65535.0)));
          if (k0 > k1) continue;
          // The owned part of the span: which samples of it are emitted does
          // not depend on where the walk starts, so this is the unrestricted
          // output filtered.
          const std::int64_t s0 = std::max(k0, own0), s1 = std::min(k1, own1);
          if (s0 > s1) {
            done = std::max(done, k1);
            continue;
          }
          if (distBefore) {
            // Water around the object is empty in both maps: jump over the
            // cube of bricks both know to be empty (as sampleAll does). The
            // rest goes four samples at a time; a sample is emitted when its
            // brick is occupied in either map (zero where only the old map
            // had it), whichever path reaches it.
            const BrickJump jump(vr);
            std::int64_t g = s0;
            interp.locate4(vr, static_cast<std::uint32_t>(g), c);
            while (g <= s1) {
              const int b[3] = {c.i[0][0] >> kBrickShift, c.i[1][0] >> kBrickShift, c.i[2][0] >> kBrickShift};
              const std::size_t brick0 = brickOf(c, 0, bd);
              const int d = std::min<int>(dist[brick0], distBefore[brick0]);
              if (d > 0) {
                g = jump.next(b, d, g, s1);
                if (g <= s1) interp.locate4(vr, static_cast<std::uint32_t>(g), c);
                continue;
              }
              if (g + 4 <= s1) {
                interp.locate4(vr, static_cast<std::uint32_t>(g + 4), next);
                interp.prefetch(next, cells);
              }
              const int lanes = static_cast<int>(std::min<std::int64_t>(4, s1 - g + 1));
              for (int l = 0; l < lanes; ++l) {
                const std::int64_t idx = interp.index(c, l);
                if (changedCells.marks && !changedCells.changed(idx)) continue;
                const std::size_t brick = brickOf(c, l, bd);
                if (dist[brick] == 0) {
                  // An all-transparent cell blends to exact zeros: no voxels read.
                  float* rgba = stage.slot();
                  if (EmptySpaceMap::bitSet(cells, idx)) interp.blendAt(c, l, idx, loaded, vox, rgba);
                  else rgba[0] = rgba[1] = rgba[2] = rgba[3] = 0.0f;
                  stage.commit(static_cast<std::uint32_t>(g + l));
                } else if (distBefore[brick] == 0) {
                  float* rgba = stage.slot();
                  rgba[0] = rgba[1] = rgba[2] = rgba[3] = 0.0f;
                  stage.commit(static_cast<std::uint32_t>(g + l));
                }
              }
              g += 4;
              std::swap(c, next);  // next holds sample g when g <= s1
            }
            done = std::max(done, k1);
            continue;
          }
          interp.locate4(vr, static_cast<std::uint32_t>(s0), c);
          for (std::int64_t g = s0; g <= s1; g += 4) {
            if (g + 4 <= s1) {
              interp.locate4(vr, static_cast<std::uint32_t>(g + 4), next);
              interp.prefetch(next);
            }
            const int lanes = static_cast<int>(std::min<std::int64_t>(4, s1 - g + 1));
            for (int l = 0; l < lanes; ++l) {
              const std::int64_t idx = interp.index(c, l);
              if (changedCells.marks && !changedCells.changed(idx)) continue;
              float* rgba = stage.slot();
              if (!dist || (dist[brickOf(c, l, bd)] == 0 && EmptySpaceMap::bitSet(cells, idx))) {
                interp.blendAt(c, l, idx, loaded, vox, rgba);
              } else {
                rgba[0] = rgba[1] = rgba[2] = rgba[3] = 0.0f;
              }
              stage.commit(static_cast<std::uint32_t>(g + l));
            }
            std::swap(c, next);
          }
          done = std::max(done, k1);
        }
        stage.emit(pixel, out);
      }
      out.flush();
    }
  }
}

