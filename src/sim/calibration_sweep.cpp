#include "sim/calibration_sweep.hpp"

#include <cmath>
#include <numbers>

#include "core/error.hpp"
#include "core/threads.hpp"
#include "sim/bmode.hpp"
#include "sim/random.hpp"

namespace pp5::sim {
namespace {


// The tracker's marker on the probe is not at the transducer: a fixed, made-up
// offset, so a calibration has a rotation and a translation to find.
Mat4 markerFromTransducer() {
  return translation(Vec3(12.0, 46.0, -4.0)) * rotationAxisAngle(glm::normalize(Vec3(0.2, 0.3, 0.93)), 100.0 * kDegToRad);
}

}  // namespace

Phantom makeNWirePhantom(const PlusPhantomDefinition& def, const Mat4& phantomToReference) {
  PP5_CHECK(!def.patterns.empty());
  Phantom ph;
  ph.name = "nwire";
  ph.background = Tissue::Water;
  Aabb box;
  for (const auto& p : def.patterns)
    for (const auto& w : p.wires) {
      const Vec3 a = transformPoint(phantomToReference, w.front), b = transformPoint(phantomToReference, w.back);
      Body body;
      body.name = "nwire." + w.name;
      body.tissue = Tissue::Nylon;
      body.distance = [a, b](const Vec3& q) { return sdf::capsule(q, a, b, 0.25); };
      body.box.extend(a);
      body.box.extend(b);
      body.box = body.box.grown(0.25);
      body.lineTarget = true;
      ph.add(std::move(body));
      ph.wires.push_back({a, b, 0.25, -10.0});
      box.extend(w.front);
      box.extend(w.back);
    }
  // A gel base 8 mm below the lowest wires, 6 mm thick, wider than the phantom.
  const Vec3 c = Vec3(box.center().x, box.center().y, box.lo.z - 11.0);
  const Vec3 half = Vec3(0.5 * box.size().x + 20.0, 0.5 * box.size().y + 20.0, 3.0);
  const Vec3 cr = transformPoint(phantomToReference, c);
  Body base;
  base.name = "nwire.base";
  base.tissue = Tissue::Gel;
  const Mat4 refToPhantom = affineInverse(phantomToReference);
  base.distance = [refToPhantom, c, half](const Vec3& q) { return sdf::box(transformPoint(refToPhantom, q), c, half); };
  const double r = glm::length(half);
  base.box = {cr - Vec3(r), cr + Vec3(r)};
  ph.add(std::move(base));
  ph.scan.surfaceZ = box.hi.z + 20.0;
  ph.scan.tgcDbPerCmMHz = tissueProperties(Tissue::Water).attenuationDbPerCmMHz;
  return ph;
}

CalibrationSweep simulateCalibrationSweep(const PlusPhantomDefinition& def, const Mat4& phantomToReference,
                                          const CalibrationSweepSettings& s, int threads) {
  if (s.frames < 1) throw InputError("a calibration sweep needs at least one frame");
  const Phantom phantom = makeNWirePhantom(def, phantomToReference);
  ProbeModel probe = probePreset("linear75");
  probe.width = s.widthPx;
  probe.height = s.heightPx;
  probe.widthMm = s.widthMm;
  probe.depthMm = s.depthMm;
  // A calibration phantom's dots in real recordings are about 2 mm wide and
  // 0.8 mm tall (fCal's, with the wires' ring-down): a 5 MHz pulse of narrow
  // band gives about that.
  probe.centerMHz = 5.0;
  probe.fractionalBandwidth = 0.25;
  probe.lateralFwhmMm = 1.2;
  probe.lateralFocusMm = 30.0;
  probe.elevationFocusMm = 30.0;
  BModeSettings bs;
  const BModeSimulator bmode(phantom, probe, bs, s.seed);

  // Where the transducer sits, in the Phantom frame: above the patterns'
  // middle, looking down (-z), its lateral axis along x, its elevation along
  // the wires (+y).
  Aabb box;
  for (const auto& p : def.patterns)
    for (const auto& w : p.wires) {
      box.extend(w.front);
      box.extend(w.back);
    }
  const Vec3 centre = box.center();
  Mat4 lookDown(1.0);
  lookDown[0] = glm::dvec4(1, 0, 0, 0);   // lateral -> +x
  lookDown[1] = glm::dvec4(0, 0, -1, 0);  // depth -> -z
  lookDown[2] = glm::dvec4(0, 1, 0, 0);   // elevation -> +y
  const double faceZ = box.hi.z + 0.30 * s.depthMm;

  CalibrationSweep out;
  out.mmPerPixel = probe.spacingX();
  const Mat4 marker = markerFromTransducer();
  out.imageToProbe = marker * probe.imageToProbe();
  const Mat4 referenceToTracker = translation(Vec3(150.0, -40.0, 320.0)) * rotationAxisAngle(Vec3(1, 0, 0), 30.0 * kDegToRad);
  // Smooth, seeded wobble: each degree of freedom a sum of two sinusoids.
  const std::uint64_t key = mixSeed(s.seed, 0xCA11B);
  auto wobble = [&](int dof, double t) {
    double v = 0.0;
    for (int h = 0; h < 2; ++h) {
      const double f = 0.7 + 1.6 * unitFromBits(latticeHash(key, dof, h, 1));
      const double ph = 2.0 * std::numbers::pi * unitFromBits(latticeHash(key, dof, h, 2));
      v += 0.5 * std::sin(2.0 * std::numbers::pi * f * t + ph);
    }
    return v;  // in [-1, 1]
  };
  std::vector<Mat4> transducerToReference(static_cast<std::size_t>(s.frames));
  for (int i = 0; i < s.frames; ++i) {
    const double t = s.frames > 1 ? static_cast<double>(i) / (s.frames - 1) : 0.5;
    const Vec3 pos(centre.x + 3.0 * wobble(0, t), centre.y + s.slideMm * (t - 0.5), faceZ + 2.0 * wobble(1, t));
    const Mat4 tilt = rotationAxisAngle(Vec3(1, 0, 0), s.tiltDeg * kDegToRad * wobble(2, t)) *
                      rotationAxisAngle(Vec3(0, 1, 0), s.tiltDeg * kDegToRad * wobble(3, t)) *
                      rotationAxisAngle(Vec3(0, 0, 1), s.tiltDeg * kDegToRad * wobble(4, t));
    transducerToReference[static_cast<std::size_t>(i)] = phantomToReference * translation(pos) * tilt * lookDown;
  }
  out.frames.resize(static_cast<std::size_t>(s.frames));
  const int n = resolveThreads(threads);
#pragma omp parallel for num_threads(n) schedule(dynamic, 1)
  for (int i = 0; i < s.frames; ++i) {
    Frame& f = out.frames[static_cast<std::size_t>(i)];
    bmode.render(transducerToReference[static_cast<std::size_t>(i)], static_cast<std::uint64_t>(i), f);
    f.index = static_cast<std::uint64_t>(i);
    f.timestamp = i / 15.0;
    const Mat4 probeToReference = transducerToReference[static_cast<std::size_t>(i)] * affineInverse(marker);
    const Mat4 truth = referenceToTracker * probeToReference;
    const std::uint64_t nk = mixSeed(s.seed, 0x7AC0 + static_cast<std::uint64_t>(i));
    Vec3 dr, dt;
    for (int a = 0; a < 3; ++a) {
      dr[a] = s.trackerNoiseDeg * kDegToRad * gaussianFromHash(latticeHash(nk, a, 0, 0));
      dt[a] = s.trackerNoiseMm * gaussianFromHash(latticeHash(nk, a, 1, 0));
    }
    const double angle = glm::length(dr);
    const Mat4 noise = translation(dt) * (angle > 0.0 ? rotationAxisAngle(dr / angle, angle) : Mat4(1.0));
    f.transforms.clear();
    f.setTransform("ProbeToTracker", truth * noise);
    f.setTransform("ReferenceToTracker", referenceToTracker);
    f.setTransform("TrueProbeToTracker", truth);
  }
  return out;
}

}  // namespace pp5::sim
