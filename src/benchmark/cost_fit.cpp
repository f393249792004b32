#include "benchmark/cost_fit.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <numeric>
#include <tuple>

#include <Eigen/Dense>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.hpp"
#include "core/grid.hpp"
#include "core/tiles.hpp"
#include "pipeline/schedule.hpp"

namespace pp5::harness {

namespace {

using nlohmann::json;

std::vector<double> numbers(const json& j, const std::string& what) {
  if (!j.is_array()) throw InputError(fmt::format("census: {} is not a list", what));
  std::vector<double> v;
  v.reserve(j.size());
  for (const json& x : j) v.push_back(x.get<double>());
  return v;
}

// Layers [lo, hi) of a per-layer list, clipped.
double sumLayers(const std::vector<double>& v, std::int64_t lo, std::int64_t hi) {
  lo = std::clamp<std::int64_t>(lo, 0, static_cast<std::int64_t>(v.size()));
  hi = std::clamp<std::int64_t>(hi, lo, static_cast<std::int64_t>(v.size()));
  return std::accumulate(v.begin() + lo, v.begin() + hi, 0.0);
}

// Least squares with non-negative coefficients (an active set: the most
// negative coefficient leaves, and the rest is fitted again).
Eigen::VectorXd fitNonNegative(const Eigen::MatrixXd& a, const Eigen::VectorXd& b) {
  const auto n = a.cols();
  std::vector<bool> on(static_cast<std::size_t>(n), true);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n);
  for (Eigen::Index round = 0; round <= n; ++round) {
    std::vector<Eigen::Index> cols;
    for (Eigen::Index i = 0; i < n; ++i)
      if (on[static_cast<std::size_t>(i)]) cols.push_back(i);
    if (cols.empty()) break;
    Eigen::MatrixXd sub(a.rows(), static_cast<Eigen::Index>(cols.size()));
    for (std::size_t k = 0; k < cols.size(); ++k) sub.col(static_cast<Eigen::Index>(k)) = a.col(cols[k]);
    // Columns scaled to unit norm, so that voxels (1e8) and frames (1e2) weigh alike.
    Eigen::VectorXd scale(sub.cols());
    for (Eigen::Index k = 0; k < sub.cols(); ++k) {
      scale(k) = sub.col(k).norm();
      if (scale(k) > 0) sub.col(k) /= scale(k);
    }
    Eigen::VectorXd y = sub.colPivHouseholderQr().solve(b);
    x.setZero();
    Eigen::Index worst = -1;
    double worstValue = 0.0;
    for (std::size_t k = 0; k < cols.size(); ++k) {
      const auto kk = static_cast<Eigen::Index>(k);
      const double v = scale(kk) > 0 ? y(kk) / scale(kk) : 0.0;
      x(cols[k]) = v;
      if (v < worstValue) {
        worstValue = v;
        worst = cols[k];
      }
    }
    if (worst < 0) return x;
    on[static_cast<std::size_t>(worst)] = false;
  }
  x = x.cwiseMax(0.0);
  return x;
}

}  // namespace

const char* roleName(RankRole r) { return r == RankRole::Host ? "host" : r == RankRole::Gp ? "GP" : "PP"; }

Census readCensus(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw InputError("census: cannot read " + path);
  json j;
  try {
    in >> j;
  } catch (const std::exception& e) {
    throw InputError(fmt::format("census: {} is not JSON: {}", path, e.what()));
  }
  try {
    if (j.value("schema", "") != "pp5echo-census-1")
      throw InputError(fmt::format("census: {} is not a pp5echo census (schema pp5echo-census-1)", path));
    Census c;
    for (int a = 0; a < 3; ++a) c.dims[static_cast<std::size_t>(a)] = j.at("grid_dims").at(a).get<std::int64_t>();
    c.width = j.at("image").at(0).get<int>();
    c.height = j.at("image").at(1).get<int>();
    c.binPx = j.at("bin_px").get<int>();
    c.binsX = j.at("bins").at(0).get<int>();
    c.binsY = j.at("bins").at(1).get<int>();
    c.frames = j.at("frames").get<double>();
    c.framePixelBytes = j.at("frame_pixel_bytes").get<double>();
    for (int a = 0; a < 3; ++a) {
      const auto ua = static_cast<std::size_t>(a);
      c.recon[ua] = numbers(j.at("recon_voxels_by_layer").at(ua), "recon_voxels_by_layer");
      c.shaded[ua] = numbers(j.at("shaded_voxels_by_layer").at(ua), "shaded_voxels_by_layer");
      c.samples[ua] = numbers(j.at("samples_by_bin_and_cell_layer").at(ua), "samples_by_bin_and_cell_layer");
      const auto cells = std::max<std::int64_t>(1, c.dims[ua] - 1);
      if (static_cast<std::int64_t>(c.recon[ua].size()) != c.dims[ua] ||
          static_cast<std::int64_t>(c.samples[ua].size()) != cells * c.binsX * c.binsY)
        throw InputError(fmt::format("census: {}: the lists of axis {} do not match the grid", path, a));
    }
    for (const json& r : j.at("frame_dirty_ranges")) {
      std::array<std::int64_t, 6> v{};
      for (std::size_t i = 0; i < 6; ++i) v[i] = r.at(i).get<std::int64_t>();
      c.frameRanges.push_back(v);
    }
    for (const json& f : j.at("dirty_voxels_by_footprint"))
      c.footprints.push_back({f.at(0).get<int>(), f.at(1).get<int>(), f.at(2).get<int>(), f.at(3).get<int>(),
                              f.at(4).get<double>()});
    if (c.frames < 1 || static_cast<double>(c.frameRanges.size()) != c.frames)
      throw InputError(fmt::format("census: {}: no frames, or a dirty range count that is not the frame count", path));
    if (c.binPx < 1 || c.width < 1 || c.height < 1 || c.binsX != (c.width + c.binPx - 1) / c.binPx ||
        c.binsY != (c.height + c.binPx - 1) / c.binPx)
      throw InputError(fmt::format("census: {}: its image, bin size and bin counts do not agree", path));
    for (const Census::Footprint& f : c.footprints)
      if (f.x0 < 0 || f.y0 < 0 || f.x0 > f.x1 || f.y0 > f.y1 || f.x1 >= c.binsX || f.y1 >= c.binsY)
        throw InputError(fmt::format("census: {}: a footprint lies outside its {}x{} bins", path, c.binsX, c.binsY));
    return c;
  } catch (const json::exception& e) {
    throw InputError(fmt::format("census: {}: {}", path, e.what()));
  }
}

std::vector<RankWork> rankWork(const Census& c, const Layout& l) {
  if (l.tileSize % c.binPx != 0)
    throw InputError(fmt::format("cost model: tile size {} is not a multiple of the census's {}-pixel bins",
                                 l.tileSize, c.binPx));
  const TileGrid tiles(c.width, c.height, l.tileSize);
  const parallel::TileOwnership own = parallel::tileOwnershipFromName(l.owner);
  const int binsPerTile = l.tileSize / c.binPx;
  auto tileOfBin = [&](int bx, int by) { return (by / binsPerTile) * tiles.cols() + bx / binsPerTile; };
  const std::size_t nBins = static_cast<std::size_t>(c.binsX * c.binsY);

  std::vector<RankWork> ranks(static_cast<std::size_t>(l.ranks()));
  RankWork& host = ranks[0];
  host.role = RankRole::Host;
  host.frames = c.frames;
  const double totalRecon = sumLayers(c.recon[0], 0, c.dims[0]);
  const bool slab = l.partition == "slab";
  if (!slab && l.partition != "tile") throw InputError("cost model: unknown partition " + l.partition);

  Grid grid;
  grid.dims = Index3(c.dims[0], c.dims[1], c.dims[2]);
  const parallel::SlabLayout slabs(grid, l.gps, parallel::SlabSplit::Longest);
  // The axis the slabs cut (the one with more than one part; x for one GP).
  int axis = 0;
  for (int a = 0; a < 3; ++a)
    if (slabs.parts()[a] > 1) axis = a;
  const auto ua = static_cast<std::size_t>(axis);
  const std::int64_t cells = std::max<std::int64_t>(1, c.dims[ua] - 1);
  const std::int64_t cells0 = std::max<std::int64_t>(1, c.dims[0] - 1);  // the x axis, for screen sums
  // The samples in the tiles `owner` of `owners` holds, and its share of the screen.
  auto samplesOfOwner = [&](int owners, int owner) {
    double samples = 0.0, share = 0.0;
    for (int by = 0; by < c.binsY; ++by)
      for (int bx = 0; bx < c.binsX; ++bx) {
        if (parallel::tileOwner(tileOfBin(bx, by), tiles.count(), owners, own) != owner) continue;
        const auto b = static_cast<std::ptrdiff_t>(by * c.binsX + bx);
        samples += std::accumulate(c.samples[0].begin() + b * cells0, c.samples[0].begin() + (b + 1) * cells0, 0.0);
        share += 1.0 / static_cast<double>(nBins);
      }
    return std::pair{samples, share};
  };

  for (int g = 0; g < l.gps; ++g) {
    RankWork& w = ranks[static_cast<std::size_t>(1 + g)];
    w.role = RankRole::Gp;
    w.frames = c.frames;
    if (slab) {
      const auto& owned = slabs.ownedCells(g);
      const std::int64_t lo = owned.lo[axis], hi = owned.hi[axis];  // cells [lo, hi)
      if (hi <= lo) continue;                                       // owns nothing
      // Its window: the voxels of its cells and a ghost layer on each side.
      w.reconVoxels = sumLayers(c.recon[ua], lo - 1, hi + 2);
      w.scanVoxels = sumLayers(c.recon[ua], lo, hi + 1);
      for (std::size_t b = 0; b < nBins; ++b)
        w.samples += std::accumulate(c.samples[ua].begin() + static_cast<std::ptrdiff_t>(b * cells + lo),
                                     c.samples[ua].begin() + static_cast<std::ptrdiff_t>(b * cells + hi), 0.0);
      for (const auto& r : c.frameRanges)
        if (r[2 * ua + 1] > r[2 * ua] && r[2 * ua] < hi + 2 && r[2 * ua + 1] > lo - 1) ++w.pixelFrames;
    } else {
      w.reconVoxels = totalRecon;
      w.pixelFrames = c.frames;
      for (const Census::Footprint& f : c.footprints) {
        bool seen = false;
        for (int by = f.y0; by <= f.y1 && !seen; ++by)
          for (int bx = f.x0; bx <= f.x1 && !seen; ++bx)
            seen = parallel::tileOwner(tileOfBin(bx, by), tiles.count(), l.gps, own) == g;
        if (seen) w.scanVoxels += f.voxels;
      }
      w.samples = samplesOfOwner(l.gps, g).first;
    }
    w.pixelBytes = w.pixelFrames * c.framePixelBytes;
    host.pixelFrames += w.pixelFrames;
  }
  host.pixelBytes = host.pixelFrames * c.framePixelBytes;
  for (int p = 0; p < l.pps; ++p) {
    RankWork& w = ranks[static_cast<std::size_t>(1 + l.gps + p)];
    w.role = RankRole::Pp;
    std::tie(w.samples, w.ownedTiles) = samplesOfOwner(l.pps, p);
  }
  return ranks;
}

namespace {

// A role's feature row for a rank of a layout (UnitCosts's order).
std::vector<double> features(RankRole role, const RankWork& w, bool tcp, double bytes, double streamS) {
  const double tcpBytes = tcp ? bytes : 0.0;
  switch (role) {
    case RankRole::Gp: return {w.frames, w.reconVoxels, w.scanVoxels, w.samples, tcpBytes};
    case RankRole::Pp: return {w.samples, streamS * w.ownedTiles, streamS, tcpBytes};
    case RankRole::Host: break;
  }
  return {w.frames, w.pixelBytes, tcpBytes};
}

// A role's costs, in features()'s order.
double* costsOf(UnitCosts& u, RankRole role) {
  return role == RankRole::Gp ? u.gp.data() : role == RankRole::Pp ? u.pp.data() : u.host.data();
}
const double* costsOf(const UnitCosts& u, RankRole role) { return costsOf(const_cast<UnitCosts&>(u), role); }

// Bytes a rank moves (sent + received), from its work and the fitted sizes.
double bytesOf(const RankWork& w, const UnitCosts& u, double streamS, const std::vector<RankWork>& all) {
  switch (w.role) {
    case RankRole::Gp: return w.pixelBytes + u.bytesPerSample * w.samples;
    case RankRole::Pp: return u.bytesPerSample * w.samples + u.tileBytesPerS * streamS * w.ownedTiles;
    case RankRole::Host: break;
  }
  double tiles = 0.0;
  for (const RankWork& r : all)
    if (r.role == RankRole::Pp) tiles += u.tileBytesPerS * streamS * r.ownedTiles;
  return w.pixelBytes + tiles;
}

}  // namespace

UnitCosts fitCosts(const Census& c, std::span<const Observation> obs) {
  if (obs.empty()) throw InputError("cost model: no measured layout to fit");
  // Each observation's work split, once; every rank measured.
  std::vector<std::vector<RankWork>> work;
  for (const Observation& o : obs) {
    work.push_back(rankWork(c, o.layout));
    if (o.cpuS.size() != work.back().size() || o.bytesMoved.size() != work.back().size())
      throw InputError(fmt::format("cost model: {} reports {} ranks, the layout has {}", o.layout.name(),
                                   o.cpuS.size(), work.back().size()));
  }
  UnitCosts u;
  // The wire sizes first: bytes per sample from the GPs (what they move beyond
  // the frames' pixels), then tile bytes from the PPs (what they move beyond
  // the samples).
  double gpBytes = 0.0, gpSamples = 0.0, ppBytes = 0.0, ppSamples = 0.0, ppScreenS = 0.0;
  for (std::size_t i = 0; i < obs.size(); ++i)
    for (std::size_t r = 0; r < work[i].size(); ++r) {
      const RankWork& w = work[i][r];
      if (w.role == RankRole::Gp) {
        gpBytes += obs[i].bytesMoved[r] - w.pixelBytes;
        gpSamples += w.samples;
      } else if (w.role == RankRole::Pp) {
        ppBytes += obs[i].bytesMoved[r];
        ppSamples += w.samples;
        ppScreenS += obs[i].streamS * w.ownedTiles;
      }
    }
  u.bytesPerSample = gpSamples > 0 ? std::max(0.0, gpBytes / gpSamples) : 0.0;
  u.tileBytesPerS = ppScreenS > 0 ? std::max(0.0, (ppBytes - u.bytesPerSample * ppSamples) / ppScreenS) : 0.0;

  for (const RankRole role : {RankRole::Host, RankRole::Gp, RankRole::Pp}) {
    std::vector<std::vector<double>> rows;
    std::vector<double> y;
    for (std::size_t i = 0; i < obs.size(); ++i)
      for (std::size_t r = 0; r < work[i].size(); ++r)
        if (work[i][r].role == role) {
          rows.push_back(features(role, work[i][r], obs[i].layout.tcp, obs[i].bytesMoved[r], obs[i].streamS));
          y.push_back(obs[i].cpuS[r]);
        }
    if (rows.empty()) continue;
    Eigen::MatrixXd a(static_cast<Eigen::Index>(rows.size()), static_cast<Eigen::Index>(rows[0].size()));
    Eigen::VectorXd b(static_cast<Eigen::Index>(rows.size()));
    for (std::size_t i = 0; i < rows.size(); ++i) {
      for (std::size_t k = 0; k < rows[i].size(); ++k)
        a(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(k)) = rows[i][k];
      b(static_cast<Eigen::Index>(i)) = y[i];
    }
    const Eigen::VectorXd x = fitNonNegative(a, b);
    u.rmsResidualS[static_cast<std::size_t>(role)] = std::sqrt((a * x - b).squaredNorm() / static_cast<double>(rows.size()));
    double* costs = costsOf(u, role);
    for (Eigen::Index k = 0; k < x.size(); ++k) costs[k] = x(k);
    u.observations += rows.size();
  }
  return u;
}

Prediction predict(const Census& c, const Layout& l, const UnitCosts& u, int cores) {
  const std::vector<RankWork> w = rankWork(c, l);
  Prediction p;
  p.rankCpuS.assign(w.size(), 0.0);
  p.rankBytes.assign(w.size(), 0.0);
  // The PPs' tick work grows with the stream's length: a few rounds settle it.
  double streamS = 1.0;
  for (int round = 0; round < 100; ++round) {
    for (std::size_t r = 0; r < w.size(); ++r) {
      const double bytes = bytesOf(w[r], u, streamS, w);
      p.rankBytes[r] = bytes;
      const std::vector<double> f = features(w[r].role, w[r], l.tcp, bytes, streamS);
      const double* k = costsOf(u, w[r].role);
      double s = 0.0;
      for (std::size_t i = 0; i < f.size(); ++i) s += k[i] * f[i];
      p.rankCpuS[r] = s;
    }
    const double sum = std::accumulate(p.rankCpuS.begin(), p.rankCpuS.end(), 0.0);
    const auto it = std::max_element(p.rankCpuS.begin(), p.rankCpuS.end());
    p.busiest = static_cast<int>(it - p.rankCpuS.begin());
    const double byCores = sum / std::max(1, std::min(cores, l.ranks()));
    p.coreBound = byCores > *it;
    const double next = std::max(byCores, *it);
    if (std::abs(next - streamS) <= 1e-12 * next) {
      streamS = next;
      p.converged = true;
      break;
    }
    streamS = next;
  }
  p.streamS = streamS;
  p.framesPerS = streamS > 0 ? c.frames / streamS : 0.0;
  return p;
}

ClusterRate clusterRate(const Census& c, const Prediction& p, double bytesPerS) {
  ClusterRate out;
  double worst = 0.0;
  for (std::size_t r = 0; r < p.rankCpuS.size(); ++r) {
    const double s = p.rankCpuS[r] + (bytesPerS > 0 ? p.rankBytes[r] / bytesPerS : 0.0);
    if (s > worst) {
      worst = s;
      out.limit = static_cast<int>(r);
    }
  }
  out.framesPerS = worst > 0 ? c.frames / worst : 0.0;
  return out;
}

}  // namespace pp5::harness
