#pragma once
// Analytic phantoms in mm, in the Reference frame: x along the phantom's long
// axis (the default sweep direction), y across it, z up. The probe looks down
// (-z) from the water surface.
//
// A phantom is an ordered list of solid bodies, each a signed distance bound
// (negative inside) with one tissue; a later body overrides earlier ones where
// they overlap, and outside every body is the background (water). Every
// distance function here is 1-Lipschitz, so |f(p)| never exceeds the distance
// from p to the body's surface: the B-mode model sphere-traces beam lines with
// it and finds even thin shells without missing them.
//
// Thin wires are also kept as line targets: the B-mode model integrates them
// over the elevation beam profile instead of sampling them on the image plane.
#include <algorithm>
#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "core/transform.hpp"

namespace pp5::sim {

enum class Tissue : std::uint8_t {
  Water,
  Vinyl,        // the doll's soft PVC
  HardPlastic,  // the doll's eyes (acrylic)
  Nylon,        // wires
  Glass,        // the tank bottom
  Skin,
  Fat,
  Muscle,
  Fascia,
  Bone,  // cortical bone
  Gel,   // tissue-mimicking spheres of the wire phantom
  Count
};
constexpr int kTissueCount = static_cast<int>(Tissue::Count);

struct TissueProperties {
  const char* name;
  // Mean backscatter: RMS speckle amplitude in dB relative to white (display
  // 255 at 0 dB gain). -infinity for a medium without scatterers.
  double backscatterDb;
  double attenuationDbPerCmMHz;  // one way
  double impedanceMRayl;
  // A rough surface: a thin layer just inside the tissue, where the beam
  // enters it, that scatters strongly (for bone: the relief of the cortex,
  // the periosteum and the outer cortex), so the surface echoes at any angle,
  // not only in the narrow specular lobe of a smooth interface. The layer
  // scatters the energy arriving at the surface: the interface's transmission
  // loss and the tissue's attenuation only darken what lies beyond it. Its
  // RMS amplitude (dB re white at normal incidence, -infinity for none)
  // falls as the cosine of the incidence angle, and it is rimMm thick along
  // the surface normal, so thicker along an oblique beam (a Lambertian
  // surface).
  double rimBackscatterDb;
  double rimMm;
};
const TissueProperties& tissueProperties(Tissue t);
const char* tissueName(Tissue t);

// Amplitude reflection coefficient for a wave going from tissue a into b.
double reflectionCoefficient(Tissue a, Tissue b);

struct Aabb {
  Vec3 lo{std::numeric_limits<double>::max()};
  Vec3 hi{std::numeric_limits<double>::lowest()};
  void extend(const Vec3& p) {
    lo = glm::min(lo, p);
    hi = glm::max(hi, p);
  }
  void extend(const Aabb& b) {
    extend(b.lo);
    extend(b.hi);
  }
  Aabb grown(double m) const { return {lo - Vec3(m), hi + Vec3(m)}; }
  bool valid() const { return lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z; }
  // Distance from p to the box (0 inside).
  double distance(const Vec3& p) const {
    const Vec3 d = glm::max(glm::max(lo - p, p - hi), Vec3(0.0));
    return glm::length(d);
  }
  Vec3 size() const { return hi - lo; }
  Vec3 center() const { return 0.5 * (lo + hi); }
};

// Signed distance bounds (negative inside, 1-Lipschitz) to build bodies from.
namespace sdf {
double sphere(const Vec3& p, const Vec3& c, double r);
// Lower bound on the distance to an axis-aligned ellipsoid (exact surface).
double ellipsoid(const Vec3& p, const Vec3& c, const Vec3& radii);
// Segment a-b swept by a sphere of radius r.
double capsule(const Vec3& p, const Vec3& a, const Vec3& b, double r);
// Segment a-b swept by a sphere whose radius goes from ra to rb (|ra-rb| < |b-a|).
double roundCone(const Vec3& p, const Vec3& a, const Vec3& b, double ra, double rb);
double box(const Vec3& p, const Vec3& c, const Vec3& halfSize);
// Slab of the given half thickness around the plane through c with unit normal n.
double slab(const Vec3& p, const Vec3& c, const Vec3& n, double halfThickness);
// Smooth union over a blend width k (still 1-Lipschitz).
double smoothUnion(double a, double b, double k);
// The layer -thickness < f < 0 just inside the surface f = 0.
inline double shell(double f, double thickness) { return f > -f - thickness ? f : -f - thickness; }
inline double intersect(double a, double b) { return a > b ? a : b; }
inline double subtract(double a, double b) { return a > -b ? a : -b; }
inline double unite(double a, double b) { return a < b ? a : b; }
}  // namespace sdf

using DistanceFn = std::function<double(const Vec3&)>;

struct Body {
  std::string name;
  Tissue tissue = Tissue::Water;
  DistanceFn distance;
  Aabb box;               // contains every point with distance < 0
  bool lineTarget = false;  // a wire: imaged as a line target, not by beam tracing
};

// A thin straight wire, imaged as a line of coherent point reflectors.
struct Wire {
  Vec3 a, b;
  double radius = 0.25;
  double echoDb = -10.0;  // peak echo of the wire crossing the image plane at right angles, dB re white
};

// How the phantom is meant to be scanned.
struct ScanSetup {
  double surfaceZ = 180.0;        // height of the probe face (the water surface)
  Vec3 sweepCenter{0.0};          // x, y of the default sweep's centre (z ignored)
  double sweepLengthMm = 190.0;   // default length of one pass along x
  double tgcDbPerCmMHz = 0.0022;  // attenuation of the medium most beams cross (TGC default)
  // Depths (from the probe face) between which the TGC ramps, as an operator
  // would set the slide pots: no gain through a water stand-off, none added
  // below the tissue.
  double tgcStartMm = 0.0;
  double tgcEndMm = 1e9;
};

class Phantom {
public:
  struct Sample {
    Tissue tissue = Tissue::Water;
    int body = -1;  // index of the body that gave the tissue, -1 for background
    // Lower bound on the distance from the point to the nearest tissue boundary.
    double clearance = std::numeric_limits<double>::infinity();
  };

  std::string name;
  Tissue background = Tissue::Water;
  std::vector<Body> bodies;
  std::vector<Wire> wires;
  ScanSetup scan;
  std::vector<std::pair<std::string, Vec3>> landmarks;

  // Tissue at p, considering every body (wires included).
  Tissue tissueAt(const Vec3& p) const { return sample(p).tissue; }
  Sample sample(const Vec3& p) const;
  // Only the listed bodies (in increasing order), as the beam tracer uses it
  // after culling the bodies that cannot touch the image plane.
  Sample sample(const Vec3& p, const std::vector<int>& bodyIndices) const;
  // Walks the line p0 + t * dir from t0 to t1 through the listed bodies
  // (sample(p, bodies)) by sphere tracing, in steps of the clearance but at
  // least `minStepMm` (so a layer thinner than that may be missed), and calls
  // onBoundary(tb, before, after) at every change of tissue, with tb placed
  // by bisection to within `tolMm` and `after` sampled just past it. Returns
  // the sample the walk ended in.
  template <class OnBoundary>
  Sample traceBoundaries(const Vec3& p0, const Vec3& dir, double t0, double t1, const std::vector<int>& bodyIndices,
                         double minStepMm, double tolMm, OnBoundary&& onBoundary) const {
    double t = t0;
    Sample s = sample(p0 + t * dir, bodyIndices);
    while (t < t1) {
      // Nothing changes within the clearance, so stepping by it cannot skip a thin shell.
      const double tNext = std::min(t + std::max(s.clearance, minStepMm), t1);
      Sample sn = sample(p0 + tNext * dir, bodyIndices);
      if (sn.tissue != s.tissue) {
        double lo = t, hi = tNext;
        while (hi - lo > tolMm) {
          const double mid = 0.5 * (lo + hi);
          const Sample sm = sample(p0 + mid * dir, bodyIndices);
          if (sm.tissue == s.tissue) {
            lo = mid;
          } else {
            hi = mid;
            sn = sm;
          }
        }
        onBoundary(0.5 * (lo + hi), s, sn);
        t = hi;
      } else {
        t = tNext;
      }
      s = sn;
    }
    return s;
  }
  // Outward unit normal of body b's surface near p (central differences).
  Vec3 normal(int b, const Vec3& p) const;
  // A named point (e.g. "left_eye"); throws InvariantError when unknown.
  Vec3 landmark(const std::string& name) const;
  // Box around the bodies whose name starts with prefix (e.g. "doll").
  Aabb boundsOf(const std::string& prefix) const;
  Aabb bounds() const;
  void add(Body b) { bodies.push_back(std::move(b)); }
};

Phantom makeDoll();
Phantom makeForearm();
Phantom makeWirePhantom();
// "doll" | "forearm" | "wires"; throws InputError for anything else.
Phantom makePhantom(const std::string& name);

}  // namespace pp5::sim
