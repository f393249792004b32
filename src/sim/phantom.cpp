#include "sim/phantom.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include "core/error.hpp"

namespace pp5::sim {

// ---- tissues ----------------------------------------------------------------

namespace {

constexpr double kNoScatter = -std::numeric_limits<double>::infinity();

// Backscatter levels are relative to the display's white, so they read as the
// tissue's brightness at 0 dB gain: muscle mid-grey, fat darker, fascia and
// skin brighter, water black. Attenuation and impedance are textbook values;
// soft vinyl and the tank's glass are what set the doll's shell echo and the
// bright, opaque tank bottom. Cortical bone is the one rough surface: besides
// its specular echo (reflection coefficient 0.63 from muscle), a layer of
// strong scattering 0.6 mm thick under its surface keeps it the brightest
// echo well away from normal incidence, and the interface's loss and the
// bone's attenuation (about 30 dB per mm two-way at 7.5 MHz) shadow
// everything beyond.
const std::array<TissueProperties, kTissueCount> kTissues = {{
    // name, backscatter dB, attenuation dB/cm/MHz, impedance MRayl, rim dB, rim mm
    {"water", kNoScatter, 0.0022, 1.48, kNoScatter, 0.0},
    {"vinyl", -40.0, 1.5, 2.60, kNoScatter, 0.0},
    {"hard_plastic", -30.0, 2.0, 3.20, kNoScatter, 0.0},
    {"nylon", -10.0, 3.0, 2.90, kNoScatter, 0.0},
    {"glass", -24.0, 12.0, 13.0, kNoScatter, 0.0},
    {"skin", -24.0, 1.0, 1.70, kNoScatter, 0.0},
    {"fat", -37.0, 0.6, 1.38, kNoScatter, 0.0},
    {"muscle", -30.0, 0.9, 1.70, kNoScatter, 0.0},
    {"fascia", -16.0, 1.0, 1.75, kNoScatter, 0.0},
    {"bone", -18.0, 20.0, 7.40, -5.0, 0.6},
    {"gel", -27.0, 0.5, 1.55, kNoScatter, 0.0},
}};

}  // namespace

const TissueProperties& tissueProperties(Tissue t) {
  const int i = static_cast<int>(t);
  PP5_CHECK_GE(i, 0);
  PP5_CHECK_LT(i, kTissueCount);
  return kTissues[static_cast<std::size_t>(i)];
}

const char* tissueName(Tissue t) { return tissueProperties(t).name; }

double reflectionCoefficient(Tissue a, Tissue b) {
  const double za = tissueProperties(a).impedanceMRayl;
  const double zb = tissueProperties(b).impedanceMRayl;
  return (zb - za) / (zb + za);
}

// ---- distance bounds ----------------------------------------------------------

namespace sdf {

double sphere(const Vec3& p, const Vec3& c, double r) { return glm::length(p - c) - r; }

double ellipsoid(const Vec3& p, const Vec3& c, const Vec3& radii) {
  // |q| - 1 in the frame scaled to a unit sphere changes by at most
  // 1/min(radii) per mm, so multiplying by min(radii) keeps it 1-Lipschitz
  // while its zero set is still exactly the ellipsoid.
  const double rmin = std::min({radii.x, radii.y, radii.z});
  return rmin * (glm::length((p - c) / radii) - 1.0);
}

double capsule(const Vec3& p, const Vec3& a, const Vec3& b, double r) {
  const Vec3 ab = b - a;
  const double t = std::clamp(glm::dot(p - a, ab) / glm::dot(ab, ab), 0.0, 1.0);
  return glm::length(p - (a + t * ab)) - r;
}

double roundCone(const Vec3& p, const Vec3& a, const Vec3& b, double ra, double rb) {
  // In the plane through the axis: x = distance from the axis, y = along it.
  // The shape is the convex hull of two circles; its side is the common
  // tangent with unit normal n = (cos phi, sin phi), sin phi = (ra - rb) / L.
  const Vec3 ab = b - a;
  const double len = glm::length(ab);
  const Vec3 pa = p - a;
  const double y = glm::dot(pa, ab) / len;
  const double x = std::sqrt(std::max(glm::dot(pa, pa) - y * y, 0.0));
  const double s = (ra - rb) / len;
  const double c = std::sqrt(std::max(1.0 - s * s, 0.0));
  const double along = -s * x + c * y;  // position along the tangent side
  if (along < 0.0) return std::sqrt(x * x + y * y) - ra;
  if (along > len * c) return std::sqrt(x * x + (y - len) * (y - len)) - rb;
  return c * x + s * y - ra;
}

double box(const Vec3& p, const Vec3& c, const Vec3& halfSize) {
  const Vec3 q = glm::abs(p - c) - halfSize;
  const double outside = glm::length(glm::max(q, Vec3(0.0)));
  const double inside = std::min(std::max({q.x, q.y, q.z}), 0.0);
  return outside + inside;
}

double slab(const Vec3& p, const Vec3& c, const Vec3& n, double halfThickness) {
  return std::abs(glm::dot(p - c, n)) - halfThickness;
}

double smoothUnion(double a, double b, double k) {
  // Polynomial smooth minimum: its gradient is a convex combination of the
  // operands' gradients, so it stays 1-Lipschitz.
  const double h = std::max(k - std::abs(a - b), 0.0) / k;
  return std::min(a, b) - h * h * k * 0.25;
}

}  // namespace sdf

// ---- Phantom ------------------------------------------------------------------

namespace {
// One body's part of a sample: bodies listed later override earlier ones.
void accumulate(Phantom::Sample& s, const Body& b, int index, const Vec3& p) {
  const double boxDist = b.box.distance(p);
  if (boxDist > 0.0) {
    s.clearance = std::min(s.clearance, boxDist);
    return;
  }
  const double f = b.distance(p);
  s.clearance = std::min(s.clearance, std::abs(f));
  if (f < 0.0) {
    s.tissue = b.tissue;
    s.body = index;
  }
}
}  // namespace

Phantom::Sample Phantom::sample(const Vec3& p) const {
  Sample s;
  s.tissue = background;
  for (std::size_t i = 0; i < bodies.size(); ++i) accumulate(s, bodies[i], static_cast<int>(i), p);
  return s;
}

Phantom::Sample Phantom::sample(const Vec3& p, const std::vector<int>& bodyIndices) const {
  Sample s;
  s.tissue = background;
  for (int i : bodyIndices) accumulate(s, bodies[static_cast<std::size_t>(i)], i, p);
  return s;
}

Vec3 Phantom::normal(int b, const Vec3& p) const {
  const DistanceFn& f = bodies[static_cast<std::size_t>(b)].distance;
  constexpr double h = 0.01;
  const Vec3 g(f(p + Vec3(h, 0, 0)) - f(p - Vec3(h, 0, 0)), f(p + Vec3(0, h, 0)) - f(p - Vec3(0, h, 0)),
               f(p + Vec3(0, 0, h)) - f(p - Vec3(0, 0, h)));
  const double len = glm::length(g);
  return len > 0.0 ? g / len : Vec3(0, 0, 1);
}

Vec3 Phantom::landmark(const std::string& n) const {
  for (const auto& [key, p] : landmarks)
    if (key == n) return p;
  throw InvariantError("phantom '" + name + "' has no landmark '" + n + "'");
}

Aabb Phantom::boundsOf(const std::string& prefix) const {
  Aabb box;
  for (const Body& b : bodies)
    if (b.name.rfind(prefix, 0) == 0) box.extend(b.box);
  return box;
}

Aabb Phantom::bounds() const { return boundsOf(""); }

// ---- building blocks shared by the phantoms -----------------------------------------

namespace {

// Adds a wire both as a thin body (so labels and the truth volume know it)
// and as a line target (so the B-mode model images it).
void addWire(Phantom& ph, const std::string& name, const Vec3& a, const Vec3& b, double radius, double echoDb) {
  Body body;
  body.name = name;
  body.tissue = Tissue::Nylon;
  body.distance = [a, b, radius](const Vec3& p) { return sdf::capsule(p, a, b, radius); };
  body.box.extend(a);
  body.box.extend(b);
  body.box = body.box.grown(radius);
  body.lineTarget = true;
  ph.add(std::move(body));
  ph.wires.push_back({a, b, radius, echoDb});
}

// The tank's glass bottom: its top face is z = 0.
void addTankBottom(Phantom& ph) {
  const Vec3 c(0.0, 0.0, -25.0), half(500.0, 500.0, 25.0);
  Body b;
  b.name = "tank.bottom";
  b.tissue = Tissue::Glass;
  b.distance = [c, half](const Vec3& p) { return sdf::box(p, c, half); };
  b.box = {c - half, c + half};
  ph.add(std::move(b));
}

Body makeBody(const std::string& name, Tissue t, DistanceFn f, const Aabb& box) {
  Body b;
  b.name = name;
  b.tissue = t;
  b.distance = std::move(f);
  b.box = box;
  return b;
}

Aabb ellipsoidBox(const Vec3& c, const Vec3& r) { return {c - r, c + r}; }
Aabb segmentBox(const Vec3& a, const Vec3& b, double r) {
  Aabb box;
  box.extend(a);
  box.extend(b);
  return box.grown(r);
}

}  // namespace

// ---- doll -----------------------------------------------------------------------
//
// A 16.5 cm vinyl baby doll lying on its back (face up, +z) with its head
// towards +x, hung in a water tank from a wire above it, as in Ohbuchi &
// Fuchs's 1990 experiment. Head and torso are a hollow shell (water inside,
// so the shell's outer and inner surfaces both echo); the limbs, ears and
// nose are solid vinyl; the eyes are hard plastic beads. A probe at the
// water surface sweeping along x cuts it into cross-sections.

namespace {

struct DollShape {
  // Head, neck and torso: the hollow part.
  Vec3 headC{60.0, 0.0, 101.0}, headR{22.0, 19.0, 20.0};
  Vec3 neckA{34.0, 0.0, 99.0}, neckB{42.0, 0.0, 100.0};
  double neckR = 10.0;
  Vec3 torsoC{8.0, 0.0, 97.0}, torsoR{30.0, 21.0, 16.0};
  double shellMm = 2.5;

  double outer(const Vec3& p) const {
    const double head = sdf::ellipsoid(p, headC, headR);
    const double neck = sdf::capsule(p, neckA, neckB, neckR);
    const double torso = sdf::ellipsoid(p, torsoC, torsoR);
    return sdf::smoothUnion(sdf::smoothUnion(head, neck, 4.0), torso, 6.0);
  }
  double cavity(const Vec3& p) const { return outer(p) + shellMm; }
};

// The limbs: each arm and leg is two tapered segments and a hand or foot.
struct Limb {
  enum Kind { Cone, Ellipsoid } kind;
  Vec3 a, b;       // cone ends, or ellipsoid centre (a) and radii (b)
  double ra, rb;   // cone radii
  double eval(const Vec3& p) const { return kind == Cone ? sdf::roundCone(p, a, b, ra, rb) : sdf::ellipsoid(p, a, b); }
  Aabb box() const {
    if (kind == Ellipsoid) return {a - b, a + b};
    Aabb box;
    box.extend(a);
    box.extend(b);
    return box.grown(std::max(ra, rb));
  }
};

std::vector<Limb> dollLimbParts(double s) {
  return {
      {Limb::Cone, {30, s * 18, 99}, {14, s * 28, 101}, 6.5, 5.8},     // upper arm
      {Limb::Cone, {14, s * 28, 101}, {-4, s * 31, 106}, 5.8, 5.0},    // forearm
      {Limb::Ellipsoid, {-10, s * 31, 108}, {7, 5, 6}, 0, 0},          // hand
      {Limb::Cone, {-14, s * 10, 95}, {-44, s * 13, 97}, 9.5, 8.0},    // thigh
      {Limb::Cone, {-44, s * 13, 97}, {-69, s * 12, 96}, 8.0, 6.0},    // shin
      {Limb::Ellipsoid, {-75, s * 12, 101}, {7, 6.5, 11}, 0, 0},       // foot
  };
}

double dollLimbs(const Vec3& p) {
  double d = std::numeric_limits<double>::infinity();
  for (double s : {-1.0, 1.0}) {
    const auto l = dollLimbParts(s);
    const double arm = sdf::smoothUnion(sdf::smoothUnion(l[0].eval(p), l[1].eval(p), 3.0), l[2].eval(p), 3.0);
    const double leg = sdf::smoothUnion(sdf::smoothUnion(l[3].eval(p), l[4].eval(p), 3.0), l[5].eval(p), 4.0);
    d = std::min({d, arm, leg});
  }
  return d;
}

Aabb dollLimbsBox() {
  Aabb box;
  for (double s : {-1.0, 1.0})
    for (const Limb& l : dollLimbParts(s)) box.extend(l.box());
  return box.grown(1.0);  // a smooth union bulges by at most k / 4
}

}  // namespace

Phantom makeDoll() {
  Phantom ph;
  ph.name = "doll";
  const DollShape shape;

  Aabb hollowBox;
  hollowBox.extend(ellipsoidBox(shape.headC, shape.headR));
  hollowBox.extend(ellipsoidBox(shape.torsoC, shape.torsoR));
  hollowBox = hollowBox.grown(2.0);  // the smooth unions bulge a little

  // Limbs: solid vinyl outside the hollow body.
  ph.add(makeBody("doll.limbs", Tissue::Vinyl,
                  [shape](const Vec3& p) { return sdf::subtract(dollLimbs(p), shape.outer(p)); }, dollLimbsBox()));

  // Head, neck and torso: a vinyl shell around water.
  ph.add(makeBody("doll.shell", Tissue::Vinyl,
                  [shape](const Vec3& p) { return sdf::shell(shape.outer(p), shape.shellMm); }, hollowBox));

  // Nose and ears: solid vinyl bumps on the shell (never inside the cavity).
  const Vec3 noseC{53.0, 0.0, 121.5}, noseR{3.5, 3.0, 3.0};
  const Vec3 earL{60.0, -19.5, 100.0}, earR{60.0, 19.5, 100.0}, earSize{5.0, 2.5, 6.5};
  Aabb featureBox = ellipsoidBox(noseC, noseR);
  featureBox.extend(ellipsoidBox(earL, earSize));
  featureBox.extend(ellipsoidBox(earR, earSize));
  ph.add(makeBody(
      "doll.features", Tissue::Vinyl,
      [shape, noseC, noseR, earL, earR, earSize](const Vec3& p) {
        const double nose = sdf::ellipsoid(p, noseC, noseR);
        const double ears = std::min(sdf::ellipsoid(p, earL, earSize), sdf::ellipsoid(p, earR, earSize));
        return sdf::subtract(std::min(nose, ears), shape.cavity(p));
      },
      featureBox));

  // Eyes: hard plastic beads set into the face (the doll's left is -y).
  const double eyeR = 3.0;
  for (const auto& [name, c] : {std::pair<const char*, Vec3>{"doll.eye_left", {61.0, -7.5, 118.0}},
                                std::pair<const char*, Vec3>{"doll.eye_right", {61.0, 7.5, 118.0}}}) {
    const Vec3 centre = c;  // clang 14 cannot capture a structured binding
    ph.add(makeBody(name, Tissue::HardPlastic, [centre, eyeR](const Vec3& p) { return sdf::sphere(p, centre, eyeR); },
                    ellipsoidBox(c, Vec3(eyeR))));
  }

  // Suspension: a wire stretched along the tank above the doll, with two
  // drops holding it at the chest and the hips.
  addWire(ph, "rig.wire", {-150.0, 0.0, 150.0}, {150.0, 0.0, 150.0}, 0.3, -10.0);
  addWire(ph, "rig.drop_chest", {30.0, 0.0, 150.0}, {30.0, 0.0, 107.0}, 0.3, -10.0);
  addWire(ph, "rig.drop_hips", {-18.0, 0.0, 150.0}, {-18.0, 0.0, 104.0}, 0.3, -10.0);

  addTankBottom(ph);

  ph.scan.surfaceZ = 180.0;
  ph.scan.sweepCenter = {0.0, 0.0, 0.0};
  ph.scan.sweepLengthMm = 190.0;
  ph.scan.tgcDbPerCmMHz = tissueProperties(Tissue::Water).attenuationDbPerCmMHz;

  ph.landmarks = {
      {"left_eye", {61.0, -7.5, 118.0}},
      {"right_eye", {61.0, 7.5, 118.0}},
      {"nose_tip", {53.0, 0.0, 124.0}},
      {"head_top", {82.0, 0.0, 101.0}},
      {"feet", {-82.0, 12.0, 101.0}},
      {"head_cavity", {60.0, 0.0, 101.0}},
      {"torso_cavity", {8.0, 0.0, 97.0}},
      {"torso_shell", {8.0, 0.0, 111.75}},  // mid-thickness of the shell on the chest
      {"thigh", {-30.0, 11.5, 96.0}},
      {"wire", {0.0, 0.0, 150.0}},
      {"water", {0.0, 60.0, 140.0}},
      {"tank_bottom", {0.0, 0.0, -5.0}},
  };
  return ph;
}

// ---- forearm ----------------------------------------------------------------------
//
// A forearm lying along x (elbow at -x, wrist at +x) in a water bath: skin,
// subcutaneous fat, muscle groups wrapped in fascia, and the radius and ulna,
// whose bright cortical surfaces cast acoustic shadows.

namespace {

constexpr double kArmAxisZ = 100.0;

// Elliptic cross-section tapering from elbow to wrist, capped at |x| = 95.
double forearmOuter(const Vec3& p) {
  const double ay = 32.0 - 0.04 * p.x;
  const double az = 24.0 - 0.03 * p.x;
  const double q = std::sqrt((p.y / ay) * (p.y / ay) + ((p.z - kArmAxisZ) / az) * ((p.z - kArmAxisZ) / az));
  // The taper makes the bound vary slightly along x; 0.99 keeps it 1-Lipschitz.
  const double section = 0.99 * std::min(ay, az) * (q - 1.0);
  return sdf::intersect(section, std::abs(p.x) - 95.0);
}

// An elliptic cylinder along x through (y, z), as a muscle belly's outline.
double ellipticCylinder(const Vec3& p, double y, double z, double ry, double rz) {
  const double q = std::sqrt(((p.y - y) / ry) * ((p.y - y) / ry) + ((p.z - z) / rz) * ((p.z - z) / rz));
  return std::min(ry, rz) * (q - 1.0);
}

constexpr double kSkinMm = 1.8;
constexpr double kFatMm = 5.0;
constexpr double kFasciaMm = 0.6;

double forearmMuscle(const Vec3& p) { return forearmOuter(p) + kSkinMm + kFatMm; }

double forearmFascia(const Vec3& p) {
  const double muscle = forearmMuscle(p);
  // Deep fascia: a thin sheet just under the fat.
  double d = sdf::shell(muscle, kFasciaMm);
  // Septa around the muscle groups.
  d = std::min(d, std::abs(ellipticCylinder(p, -15.0, 112.0, 10.0, 6.0)) - 0.5 * kFasciaMm);
  d = std::min(d, std::abs(ellipticCylinder(p, 15.0, 113.0, 11.0, 6.5)) - 0.5 * kFasciaMm);
  d = std::min(d, std::abs(ellipticCylinder(p, 0.0, 86.0, 17.0, 6.5)) - 0.5 * kFasciaMm);
  d = std::min(d, std::abs(ellipticCylinder(p, -21.0, 95.0, 6.0, 8.0)) - 0.5 * kFasciaMm);
  // Interosseous membrane between the two bones.
  d = std::min(d, sdf::intersect(sdf::slab(p, {0, 0, 101.0}, {0, 0, 1}, 0.5 * kFasciaMm), std::abs(p.y) - 13.0));
  return sdf::intersect(d, muscle);
}

}  // namespace

Phantom makeForearm() {
  Phantom ph;
  ph.name = "forearm";
  const Aabb armBox{{-95.0, -39.0, 70.0}, {95.0, 39.0, 130.0}};
  ph.add(makeBody("arm.skin", Tissue::Skin, forearmOuter, armBox));
  ph.add(makeBody("arm.fat", Tissue::Fat, [](const Vec3& p) { return forearmOuter(p) + kSkinMm; }, armBox));
  ph.add(makeBody("arm.muscle", Tissue::Muscle, forearmMuscle, armBox));
  ph.add(makeBody("arm.fascia", Tissue::Fascia, forearmFascia, armBox));

  const Vec3 radA{-95.0, 14.0, 101.0}, radB{95.0, 11.0, 103.0};
  const Vec3 ulnA{-95.0, -11.0, 99.0}, ulnB{95.0, -13.0, 99.0};
  ph.add(makeBody("arm.radius", Tissue::Bone,
                  [radA, radB](const Vec3& p) { return sdf::roundCone(p, radA, radB, 6.0, 7.5); },
                  segmentBox(radA, radB, 7.5)));
  ph.add(makeBody("arm.ulna", Tissue::Bone,
                  [ulnA, ulnB](const Vec3& p) { return sdf::roundCone(p, ulnA, ulnB, 7.5, 5.0); },
                  segmentBox(ulnA, ulnB, 7.5)));
  addTankBottom(ph);

  ph.scan.surfaceZ = 128.0;  // a few mm of water stand-off above the skin
  ph.scan.sweepCenter = {0.0, 0.0, 0.0};
  ph.scan.sweepLengthMm = 150.0;
  ph.scan.tgcDbPerCmMHz = 0.7;  // soft tissue, what a sonographer would set
  ph.scan.tgcStartMm = ph.scan.surfaceZ - (kArmAxisZ + 24.0);  // the skin on top
  ph.scan.tgcEndMm = ph.scan.surfaceZ - (kArmAxisZ - 24.0);    // the skin below

  ph.landmarks = {
      {"radius_centre", {0.0, 12.5, 102.0}},
      {"ulna_centre", {0.0, -12.0, 99.0}},
      {"skin", {0.0, 0.0, 123.1}},
      {"fat", {0.0, 0.0, 119.0}},
      {"muscle", {0.0, 0.0, 95.0}},
      {"water", {0.0, 60.0, 100.0}},
      {"tank_bottom", {0.0, 0.0, -5.0}},
  };
  return ph;
}

// ---- wires ------------------------------------------------------------------------
//
// A calibration phantom in water: three layers of N-shaped wire triplets
// (two wires along x, one diagonal between them, as in PLUS's fCal phantoms),
// a crossing pair, and tissue-mimicking gel spheres of 3, 5, 8 and 12 mm.

Phantom makeWirePhantom() {
  Phantom ph;
  ph.name = "wires";
  constexpr double half = 50.0, wireR = 0.2;
  int layer = 0;
  for (double z : {90.0, 70.0, 50.0}) {
    const std::string n = "wires.n" + std::to_string(layer);
    const double flip = (layer % 2 == 0) ? 1.0 : -1.0;
    addWire(ph, n + ".a", {-half, -15.0, z}, {half, -15.0, z}, wireR, -10.0);
    addWire(ph, n + ".diag", {-half, -15.0 * flip, z}, {half, 15.0 * flip, z}, wireR, -10.0);
    addWire(ph, n + ".c", {-half, 15.0, z}, {half, 15.0, z}, wireR, -10.0);
    ++layer;
  }
  addWire(ph, "wires.cross1", {-half, -20.0, 30.0}, {half, 20.0, 30.0}, wireR, -10.0);
  addWire(ph, "wires.cross2", {-half, 20.0, 30.0}, {half, -20.0, 30.0}, wireR, -10.0);

  const std::array<std::pair<double, double>, 4> spheres = {{{3.0, -30.0}, {5.0, -10.0}, {8.0, 10.0}, {12.0, 30.0}}};
  for (const auto& [diameter, x] : spheres) {
    const Vec3 c{x, 30.0, 60.0};
    const double r = 0.5 * diameter;
    const std::string n = "wires.sphere_" + std::to_string(static_cast<int>(diameter)) + "mm";
    ph.add(makeBody(n, Tissue::Gel, [c, r](const Vec3& p) { return sdf::sphere(p, c, r); }, ellipsoidBox(c, Vec3(r))));
    ph.landmarks.push_back({n.substr(6), c});
  }
  addTankBottom(ph);

  ph.scan.surfaceZ = 120.0;
  ph.scan.sweepCenter = {0.0, 0.0, 0.0};
  ph.scan.sweepLengthMm = 100.0;
  ph.scan.tgcDbPerCmMHz = tissueProperties(Tissue::Water).attenuationDbPerCmMHz;

  ph.landmarks.push_back({"wire", {0.0, -15.0, 90.0}});
  ph.landmarks.push_back({"water", {0.0, 0.0, 110.0}});
  ph.landmarks.push_back({"tank_bottom", {0.0, 0.0, -5.0}});
  return ph;
}

Phantom makePhantom(const std::string& name) {
  if (name == "doll") return makeDoll();
  if (name == "forearm") return makeForearm();
  if (name == "wires") return makeWirePhantom();
  throw InputError("sim.phantom: unknown phantom '" + name + "' (expected doll, forearm or wires)");
}

}  // namespace pp5::sim
