// The B-mode simulator's rendering (sim/bmode.hpp): beams traced through the
// phantom, wires and scatterers splatted with the PSF, the image formed.
#include "sim/bmode.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include "core/error.hpp"
#include "sim/random.hpp"
#include "sim/bmode_detail.hpp"

namespace pp5::sim {

namespace {

// exp(-x) for x in [0, 4.5] (PSF weights cut at 3 sigma), by table.
class NegExpTable {
public:
  static constexpr int kSize = 4096;
  static constexpr double kMax = 0.5 * kPsfCutoff * kPsfCutoff;
  NegExpTable() {
    for (int i = 0; i <= kSize; ++i) v_[static_cast<std::size_t>(i)] = static_cast<float>(std::exp(-kMax * i / kSize));
  }
  float operator()(double x) const {
    const int i = static_cast<int>(x * (kSize / kMax) + 0.5);
    return i > kSize ? 0.0f : v_[static_cast<std::size_t>(i)];
  }

private:
  std::array<float, kSize + 1> v_{};
};

// cos and sin of 2 pi * fraction, by table.
class PhaseTable {
public:
  static constexpr int kBits = 12;
  static constexpr int kSize = 1 << kBits;
  PhaseTable() {
    for (int i = 0; i < kSize; ++i) {
      const double a = 2.0 * std::numbers::pi * i / kSize;
      cos_[static_cast<std::size_t>(i)] = static_cast<float>(std::cos(a));
      sin_[static_cast<std::size_t>(i)] = static_cast<float>(std::sin(a));
    }
  }
  // Phase given in cycles (any real number).
  void lookup(double cycles, float& c, float& s) const {
    const auto i = static_cast<std::size_t>(static_cast<std::int64_t>(std::floor(cycles * kSize)) & (kSize - 1));
    c = cos_[i];
    s = sin_[i];
  }

private:
  std::array<float, kSize> cos_{}, sin_{};
};

const NegExpTable& negExp() {
  static const NegExpTable t;
  return t;
}
const PhaseTable& phaseTable() {
  static const PhaseTable t;
  return t;
}

}  // namespace

// ---- rendering ----------------------------------------------------------------------

void BModeSimulator::splat(Workspace& ws, double cu, double v, float re, float im) const {
  const double rc = (v - firstSubV_) / subDy_;
  const double reach = kPsfCutoff * sigmaAx_ / subDy_;
  const int r0 = std::max(0, static_cast<int>(std::ceil(rc - reach)));
  const int r1 = std::min(subRows_ - 1, static_cast<int>(std::floor(rc + reach)));
  const double cf = std::floor(cu);
  const int c0 = static_cast<int>(cf) + guard_;
  if (c0 < 0 || c0 + 1 >= ws.cols) return;
  const float fu = static_cast<float>(cu - cf);
  const double inv2s2 = 0.5 / (sigmaAx_ * sigmaAx_);
  const NegExpTable& ex = negExp();
  for (int r = r0; r <= r1; ++r) {
    const double d = (r - rc) * subDy_;
    const float w = ex(d * d * inv2s2);
    float* pre = &ws.re[static_cast<std::size_t>(r) * static_cast<std::size_t>(ws.cols) + static_cast<std::size_t>(c0)];
    float* pim = &ws.im[static_cast<std::size_t>(r) * static_cast<std::size_t>(ws.cols) + static_cast<std::size_t>(c0)];
    const float w0 = (1.0f - fu) * w, w1 = fu * w;
    pre[0] += w0 * re;
    pim[0] += w0 * im;
    pre[1] += w1 * re;
    pim[1] += w1 * im;
  }
}

// Traces every beam line (image column) down through the phantom: fills the
// per-column tables of transmission and scattering strength, and adds the
// specular echo of every interface crossed.
void BModeSimulator::traceColumns(const FrameGeometry& g, const std::vector<int>& bodies, Workspace& ws) const {
  const double sx = probe_.spacingX();
  const double f0 = probe_.centerMHz;
  const double specSigma = settings_.specularWidthDeg * std::numbers::pi / 180.0;
  const PhaseTable& phase = phaseTable();
  const auto fineRows = static_cast<std::size_t>(fineRows_);

  for (int c = 0; c < probe_.width; ++c) {
    const Vec3 top = g.origin + (c * sx) * g.u;
    float* echo = &ws.echo[static_cast<std::size_t>(c) * fineRows];
    float* trans = &ws.trans[static_cast<std::size_t>(c) * fineRows];
    std::uint8_t* mask = &ws.mask[static_cast<std::size_t>(c) * static_cast<std::size_t>(ws.maskRows)];

    double segStart = 0.0;
    double attenDb = 0.0;  // two-way attenuation down to segStart
    double tInterfaces = 1.0;
    int nextFine = 0;
    // The rim of the tissue the beam last entered (a thin, strongly
    // scattering layer under its surface): its backscatter amplitude, the
    // transmission down to the surface, and the depth where the beam leaves it.
    double rimAmp = 0.0, rimTrans = 0.0, rimEnd = -1.0;

    // Fills the tables for fine rows whose depth lies in [segStart, end).
    auto fillSegment = [&](Tissue tissue, double end) {
      const TissueProperties& tp = tissueProperties(tissue);
      const double slope = ideal_ ? 0.0 : 2.0 * tp.attenuationDbPerCmMHz * f0 / 10.0;  // dB per mm, two-way
      const double backscatter = std::isfinite(tp.backscatterDb) ? std::pow(10.0, tp.backscatterDb / 20.0) : 0.0;
      // Fine rows before this one lie in the rim.
      const int rimRows = rimEnd > segStart ? static_cast<int>(std::ceil(rimEnd / fineDy_ - 0.5)) : 0;
      int fEnd = static_cast<int>(std::ceil(end / fineDy_ - 0.5));
      fEnd = std::min(fEnd, fineRows_);
      if (nextFine >= fEnd) return;
      const double v0 = (nextFine + 0.5) * fineDy_;
      double t = tInterfaces * std::pow(10.0, -(attenDb + slope * (v0 - segStart)) / 20.0);
      const double step = std::pow(10.0, -slope * fineDy_ / 20.0);
      bool anyEcho = false;
      for (int f = nextFine; f < fEnd; ++f) {
        // The rim scatters the energy that reaches the surface; the
        // interface's loss and the tissue's attenuation act beyond it.
        const bool rim = f < rimRows;
        trans[f] = static_cast<float>(rim ? rimTrans : t);
        // Echoes far below the noise (deep in a shadow) are left out.
        const double e = rim ? rimAmp * rimTrans : backscatter * t;
        echo[f] = e > echoCutoff_[static_cast<std::size_t>(f)] ? static_cast<float>(e) : 0.0f;
        anyEcho = anyEcho || echo[f] > 0.0f;
        t *= step;
      }
      if (anyEcho) {
        const int m0 = std::max(0, static_cast<int>(v0 / kMaskDy));
        const int m1 = std::min(ws.maskRows - 1, static_cast<int>(((fEnd - 0.5) * fineDy_) / kMaskDy));
        for (int m = m0; m <= m1; ++m) mask[m] = 1;
      }
      nextFine = fEnd;
    };

    const Phantom::Sample last = phantom_.traceBoundaries(
        top, g.v, 0.0, vMax_, bodies, kMinStepMm, kBoundaryTolMm,
        [&](double vb, const Phantom::Sample& s, const Phantom::Sample& sn) {
          fillSegment(s.tissue, vb);
          if (ideal_) {  // no attenuation, echo, loss or rim at the boundary
            segStart = vb;
            return;
          }
          const TissueProperties& tp = tissueProperties(s.tissue);
          attenDb += 2.0 * tp.attenuationDbPerCmMHz * f0 / 10.0 * (vb - segStart);
          const double tAbove = tInterfaces * std::pow(10.0, -attenDb / 20.0);

          // Specular echo: the surface is that of whichever body's distance is
          // smaller at the boundary.
          const Vec3 pb = top + vb * g.v;
          int body = s.body;
          if (body < 0 || (sn.body >= 0 && std::abs(phantom_.bodies[static_cast<std::size_t>(sn.body)].distance(pb)) <
                                               std::abs(phantom_.bodies[static_cast<std::size_t>(body)].distance(pb))))
            body = sn.body;
          double angleFactor = 1.0, cosA = 1.0;
          if (body >= 0) {
            cosA = std::min(1.0, std::abs(glm::dot(phantom_.normal(body, pb), g.v)));
            const double angle = std::acos(cosA);
            angleFactor = kDiffuseFloor + (1.0 - kDiffuseFloor) * std::exp(-0.5 * angle * angle / (specSigma * specSigma));
          }
          // The echo is that of the energy arriving at the surface (tAbove):
          // this interface's own transmission loss only darkens what lies beyond.
          const double r = reflectionCoefficient(s.tissue, sn.tissue);
          const int fb = std::min(fineRows_ - 1, static_cast<int>(vb / fineDy_));
          const double amp = r * angleFactor * tAbove * reflectorNorm_[static_cast<std::size_t>(fb)];
          float cs, sn2;
          phase.lookup(-k2_ * vb / (2.0 * std::numbers::pi), cs, sn2);
          splat(ws, c, vb, static_cast<float>(amp * cs), static_cast<float>(amp * sn2));

          tInterfaces *= (1.0 - r * r);
          // Entering a tissue with a rough surface: a Lambertian layer, rimMm
          // thick along the surface normal (so an oblique beam crosses more of
          // it) and fainter as the surface turns away from the beam.
          const TissueProperties& tn = tissueProperties(sn.tissue);
          if (tn.rimMm > 0.0 && std::isfinite(tn.rimBackscatterDb)) {
            rimAmp = std::pow(10.0, tn.rimBackscatterDb / 20.0) * cosA;
            rimTrans = tAbove;
            rimEnd = vb + tn.rimMm / std::max(cosA, kMinRimCos);
          } else {
            rimEnd = -1.0;
          }
          segStart = vb;
        });
    fillSegment(last.tissue, vMax_ + fineDy_);
    // Rows past the end keep the last values.
    for (int f = nextFine; f < fineRows_; ++f) {
      trans[f] = nextFine > 0 ? trans[nextFine - 1] : 1.0f;
      echo[f] = nextFine > 0 ? echo[nextFine - 1] : 0.0f;
    }
  }
}

// Wires are line targets: each is sampled finely where it passes through the
// elevation beam, and the samples add coherently, so a wire across the beam
// is a bright dot while one along the beam cancels out except at its ends.
void BModeSimulator::addWires(const FrameGeometry& g, Workspace& ws) const {
  const double sx = probe_.spacingX();
  const double ds = 0.5 * std::min({sigmaAx_, probe_.lateralSigmaMm(probe_.lateralFocusMm),
                                    probe_.elevationSigmaMm(probe_.elevationFocusMm)});
  const PhaseTable& phase = phaseTable();
  const NegExpTable& ex = negExp();
  const auto fineRows = static_cast<std::size_t>(fineRows_);
  for (const Wire& w : phantom_.wires) {
    const Vec3 dir = w.b - w.a;
    const double len = glm::length(dir);
    if (len <= 0.0) continue;
    const Vec3 unit = dir / len;
    // The part of the wire inside the slab |e| <= maxHalfSlab.
    const double ea = glm::dot(g.n, w.a - g.origin);
    const double de = glm::dot(g.n, unit);
    double s0 = 0.0, s1 = len;
    if (std::abs(de) > 1e-12) {
      const double sa = (-maxHalfSlab_ - ea) / de, sb = (maxHalfSlab_ - ea) / de;
      s0 = std::max(s0, std::min(sa, sb));
      s1 = std::min(s1, std::max(sa, sb));
    } else if (std::abs(ea) > maxHalfSlab_) {
      continue;
    }
    const double amp0 = std::pow(10.0, w.echoDb / 20.0) * ds;
    for (double s = s0; s <= s1; s += ds) {
      const Vec3 d = w.a + s * unit - g.origin;
      const double u = glm::dot(g.u, d), v = glm::dot(g.v, d), e = glm::dot(g.n, d);
      if (v < 0.0 || v >= vMax_) continue;
      const double cu = u / sx;
      if (cu < -guard_ || cu > probe_.width - 1 + guard_) continue;
      const auto f = static_cast<std::size_t>(v / fineDy_);
      const double x = e * e * invTwoSigmaE2_[f];
      if (x > NegExpTable::kMax) continue;
      const double sigmaE = 1.0 / std::sqrt(2.0 * invTwoSigmaE2_[f]);
      const auto col = static_cast<std::size_t>(std::clamp(static_cast<int>(std::lround(cu)), 0, probe_.width - 1));
      const double a = amp0 / (std::sqrt(2.0 * std::numbers::pi) * sigmaE) * ex(x) * ws.trans[col * fineRows + f];
      float cs, sn;
      phase.lookup(-k2_ * v / (2.0 * std::numbers::pi), cs, sn);
      splat(ws, cu, v, static_cast<float>(a * cs), static_cast<float>(a * sn));
    }
  }
}

// Visits the lattice scatterers within the elevation beam, line by line along
// the world axis closest to the beam's elevation direction, and adds each one's
// echo. Lines whose neighbourhood holds no scattering tissue are skipped
// whole, which is most of a water tank.
std::size_t BModeSimulator::addScatterers(const FrameGeometry& g, Workspace& ws) const {
  const double sx = probe_.spacingX();
  const double h = pitch_;
  const int W = probe_.width;
  const auto fineRows = static_cast<std::size_t>(fineRows_);
  const PhaseTable& phase = phaseTable();
  const NegExpTable& ex = negExp();
  const std::uint64_t seedKey = mixSeed(seed_, 0x5ca77e25u);

  int a = 0;
  for (int i = 1; i < 3; ++i)
    if (std::abs(g.n[i]) > std::abs(g.n[a])) a = i;
  const int b = (a + 1) % 3, c = (a + 2) % 3;

  const double uLo = -guard_ * sx, uHi = (W - 1 + guard_) * sx;
  // Lattice lines that can reach the slab around the image.
  double bMin = 1e300, bMax = -1e300, cMin = 1e300, cMax = -1e300;
  for (double u : {uLo, uHi})
    for (double v : {0.0, vMax_})
      for (double e : {-maxHalfSlab_, maxHalfSlab_}) {
        const Vec3 p = g.origin + u * g.u + v * g.v + e * g.n;
        bMin = std::min(bMin, p[b]);
        bMax = std::max(bMax, p[b]);
        cMin = std::min(cMin, p[c]);
        cMax = std::max(cMax, p[c]);
      }
  const auto ib0 = static_cast<std::int64_t>(std::floor(bMin / h)) - 1;
  const auto ib1 = static_cast<std::int64_t>(std::floor(bMax / h)) + 1;
  const auto ic0 = static_cast<std::int64_t>(std::floor(cMin / h)) - 1;
  const auto ic1 = static_cast<std::int64_t>(std::floor(cMax / h)) + 1;

  const double na = g.n[a];
  const double invAbsNa = 1.0 / std::abs(na);

  // Is there scattering tissue in columns [u0, u1] x depths [v0, v1]?
  auto anyTissue = [&](double u0, double u1, double v0, double v1) {
    const int cA = std::clamp(static_cast<int>(std::floor(u0 / sx)), 0, W - 1);
    const int cB = std::clamp(static_cast<int>(std::ceil(u1 / sx)), 0, W - 1);
    const int mA = std::clamp(static_cast<int>(std::floor(v0 / kMaskDy)), 0, ws.maskRows - 1);
    const int mB = std::clamp(static_cast<int>(std::floor(v1 / kMaskDy)), 0, ws.maskRows - 1);
    for (int col = cA; col <= cB; ++col) {
      const std::uint8_t* m = &ws.mask[static_cast<std::size_t>(col) * static_cast<std::size_t>(ws.maskRows)];
      for (int r = mA; r <= mB; ++r)
        if (m[r]) return true;
    }
    return false;
  };

  std::size_t count = 0;
  for (std::int64_t ib = ib0; ib <= ib1; ++ib) {
    for (std::int64_t ic = ic0; ic <= ic1; ++ic) {
      // The line through the centres of cells (., ib, ic).
      Vec3 q(0.0);
      q[b] = (static_cast<double>(ib) + 0.5) * h;
      q[c] = (static_cast<double>(ic) + 0.5) * h;
      const Vec3 d0 = q - g.origin;
      const double t0 = -glm::dot(g.n, d0) / na;  // where it crosses the image plane
      const double u0 = glm::dot(g.u, d0) + t0 * g.u[a];
      const double v0 = glm::dot(g.v, d0) + t0 * g.v[a];
      const double vc = std::clamp(v0, 0.0, vMax_ - fineDy_);
      const double half = halfSlab_[static_cast<std::size_t>(vc / fineDy_)] + 1.8 * h;
      const double tH = half * invAbsNa;
      const double du = tH * std::abs(g.u[a]) + h, dv = tH * std::abs(g.v[a]) + h;
      if (u0 + du < uLo || u0 - du > uHi || v0 + dv < 0.0 || v0 - dv > vMax_) continue;
      if (!anyTissue(u0 - du, u0 + du, v0 - dv, v0 + dv)) continue;

      const auto ia0 = static_cast<std::int64_t>(std::floor((t0 - tH) / h));
      const auto ia1 = static_cast<std::int64_t>(std::floor((t0 + tH) / h));
      std::int64_t idx[3];
      idx[b] = ib;
      idx[c] = ic;
      for (std::int64_t ia = ia0; ia <= ia1; ++ia) {
        idx[a] = ia;
        const std::uint64_t key = latticeHash(seedKey, idx[0], idx[1], idx[2]);
        // Offset of the scatterer from the line point at t = 0.
        Vec3 off;
        off[a] = (static_cast<double>(ia) + unitFromBits(key)) * h;
        off[b] = (unitFromBits(key >> 16) - 0.5) * h;
        off[c] = (unitFromBits(key >> 32) - 0.5) * h;
        const Vec3 d = d0 + off;
        const double v = glm::dot(g.v, d);
        if (v < 0.0 || v >= vMax_) continue;
        const double cu = glm::dot(g.u, d) / sx;
        if (cu < -guard_ || cu >= W - 1 + guard_) continue;
        const auto f = static_cast<std::size_t>(v / fineDy_);
        const double e = glm::dot(g.n, d);
        const double x = e * e * invTwoSigmaE2_[f];
        if (x > NegExpTable::kMax) continue;
        const auto col = static_cast<std::size_t>(std::clamp(static_cast<int>(cu + 0.5), 0, W - 1));
        const float strength = ws.echo[col * fineRows + f];
        if (strength == 0.0f) continue;
        const float amp = gaussianFromBits(key >> 48) * strength * ex(x) * speckleNorm_[f];
        float cs, sn;
        phase.lookup(-k2_ * v / (2.0 * std::numbers::pi), cs, sn);
        splat(ws, cu, v, amp * cs, amp * sn);
        ++count;
      }
    }
  }
  return count;
}

// Lateral PSF, TGC, noise and envelope per sub-row; an image row is the mean
// envelope of its sub-rows (the detected signal low-passed and decimated to
// the pixel grid), then log-compressed.
void BModeSimulator::formImage(std::uint64_t frameIndex, Workspace& ws, Frame& out,
                               BModeDebug* debug) const {
  const int W = probe_.width, H = probe_.height;
  const float noiseSigma = static_cast<float>(std::pow(10.0, settings_.noiseDb / 20.0) / std::sqrt(2.0));
  const std::uint64_t noiseKey = mixSeed(mixSeed(seed_, 0x4e015eu), frameIndex);

  if (debug) {
    debug->width = W;
    debug->subRows = subRows_;
    debug->oversample = osf_;
    debug->envelope.assign(static_cast<std::size_t>(W) * static_cast<std::size_t>(subRows_), 0.0f);
  }
  ws.rowSum.assign(static_cast<std::size_t>(W), 0.0f);
  out.allocate(W, H, PixelType::U8);
  std::uint8_t* px = out.u8();
  for (int r = 0; r < subRows_; ++r) {
    const auto& k = kernels_[static_cast<std::size_t>(r)];
    const int rad = kernelRadius_[static_cast<std::size_t>(r)];
    const float gain = rowGain_[static_cast<std::size_t>(r)];
    const std::size_t base = static_cast<std::size_t>(r) * static_cast<std::size_t>(ws.cols) + static_cast<std::size_t>(guard_ - rad);
    const float* re = &ws.re[base];
    const float* im = &ws.im[base];
    for (int col = 0; col < W; ++col) {
      float sr = 0.0f, si = 0.0f;
      for (int t = 0; t <= 2 * rad; ++t) {
        sr += k[static_cast<std::size_t>(t)] * re[col + t];
        si += k[static_cast<std::size_t>(t)] * im[col + t];
      }
      const std::uint64_t nk = latticeHash(noiseKey, r, col, 0);
      sr = sr * gain + noiseSigma * gaussianFromBits(nk);
      si = si * gain + noiseSigma * gaussianFromBits(nk >> 16);
      const float env = std::sqrt(sr * sr + si * si);
      if (debug) debug->envelope[static_cast<std::size_t>(r) * static_cast<std::size_t>(W) + static_cast<std::size_t>(col)] = env;
      ws.rowSum[static_cast<std::size_t>(col)] += env;
    }
    if ((r + 1) % osf_ == 0) {
      std::uint8_t* row = px + static_cast<std::size_t>(r / osf_) * static_cast<std::size_t>(W);
      for (int col = 0; col < W; ++col) {
        row[col] = static_cast<std::uint8_t>(std::lround(pixelFromAmplitude(ws.rowSum[static_cast<std::size_t>(col)] / osf_)));
        ws.rowSum[static_cast<std::size_t>(col)] = 0.0f;
      }
    }
  }
}

void BModeSimulator::render(const Mat4& probeToReference, std::uint64_t frameIndex, Frame& out,
                            BModeDebug* debug) const {
  FrameGeometry g;
  const double sx = probe_.spacingX();
  g.u = glm::normalize(Vec3(probeToReference[0]));
  g.v = glm::normalize(Vec3(probeToReference[1]));
  g.n = glm::normalize(Vec3(probeToReference[2]));
  g.origin = transformPoint(probeToReference, Vec3(-0.5 * (probe_.width - 1) * sx, 0.0, 0.0));

  // Bodies that can touch the image rectangle; wires are imaged separately.
  std::vector<int> bodies;
  const double uMax = (probe_.width - 1) * sx;
  for (std::size_t i = 0; i < phantom_.bodies.size(); ++i) {
    const Body& body = phantom_.bodies[i];
    if (body.lineTarget) continue;
    double eLo = 1e300, eHi = -1e300, uLo = 1e300, uHi = -1e300, vLo = 1e300, vHi = -1e300;
    for (int k = 0; k < 8; ++k) {
      const Vec3 p((k & 1) ? body.box.hi.x : body.box.lo.x, (k & 2) ? body.box.hi.y : body.box.lo.y,
                   (k & 4) ? body.box.hi.z : body.box.lo.z);
      const Vec3 d = p - g.origin;
      const double e = glm::dot(g.n, d), u = glm::dot(g.u, d), v = glm::dot(g.v, d);
      eLo = std::min(eLo, e);
      eHi = std::max(eHi, e);
      uLo = std::min(uLo, u);
      uHi = std::max(uHi, u);
      vLo = std::min(vLo, v);
      vHi = std::max(vHi, v);
    }
    if (eLo > 0.0 || eHi < 0.0 || uLo > uMax || uHi < 0.0 || vLo > vMax_ || vHi < 0.0) continue;
    bodies.push_back(static_cast<int>(i));
  }

  thread_local Workspace ws;
  ws.cols = probe_.width + 2 * guard_;
  const std::size_t bufSize = static_cast<std::size_t>(subRows_) * static_cast<std::size_t>(ws.cols);
  ws.re.assign(bufSize, 0.0f);
  ws.im.assign(bufSize, 0.0f);
  ws.echo.resize(static_cast<std::size_t>(probe_.width) * static_cast<std::size_t>(fineRows_));
  ws.trans.resize(ws.echo.size());
  ws.maskRows = static_cast<int>(std::ceil(vMax_ / kMaskDy)) + 1;
  ws.mask.assign(static_cast<std::size_t>(probe_.width) * static_cast<std::size_t>(ws.maskRows), 0);

  traceColumns(g, bodies, ws);
  addWires(g, ws);
  const std::size_t n = addScatterers(g, ws);
  if (debug) debug->scatterers = n;
  formImage(frameIndex, ws, out, debug);
}

}  // namespace pp5::sim
