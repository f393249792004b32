// The PLUS configuration's calibration elements: Segmentation and the
// N-wire PhantomDefinition, read and checked as PLUS's calibration reads them.
#include <cmath>

#include "formats/plus_xml.hpp"

namespace pp5::plusxml {

PlusSegmentation readSegmentation(const XmlFile& f, pugi::xml_node n) {
  ElementReader e(f, n, "Segmentation");
  PlusSegmentation s;
  auto need = [&](const char* name) {
    auto v = e.real(name);
    if (!v) e.fail("{} is missing", name);
    return *v;
  };
  s.approximateSpacingMmPerPixel = need("ApproximateSpacingMmPerPixel");
  if (!(s.approximateSpacingMmPerPixel > 0.0 && s.approximateSpacingMmPerPixel < 10.0))
    e.fail("ApproximateSpacingMmPerPixel {} is not in (0, 10) mm", s.approximateSpacingMmPerPixel);
  auto opt = [&](const char* name, double& field, double lo, double hi) {
    if (auto v = e.real(name)) {
      if (!(*v >= lo && *v <= hi)) e.fail("{} {} is not in [{}, {}]", name, *v, lo, hi);
      field = *v;
    }
  };
  opt("MorphologicalOpeningCircleRadiusMm", s.morphologicalOpeningCircleRadiusMm, 0.0, 20.0);
  opt("MorphologicalOpeningBarSizeMm", s.morphologicalOpeningBarSizeMm, 0.0, 100.0);
  opt("MaxLinePairDistanceErrorPercent", s.maxLinePairDistanceErrorPercent, 0.0, 100.0);
  opt("AngleToleranceDegrees", s.angleToleranceDegrees, 0.0, 90.0);
  opt("MaxAngleDifferenceDegrees", s.maxAngleDifferenceDegrees, 0.0, 90.0);
  opt("MinThetaDegrees", s.minThetaDegrees, -90.0, 90.0);
  opt("MaxThetaDegrees", s.maxThetaDegrees, -90.0, 90.0);
  opt("MaxLineShiftMm", s.maxLineShiftMm, 0.0, 1000.0);
  opt("ThresholdImagePercent", s.thresholdImagePercent, 0.0, 100.0);
  opt("CollinearPointsMaxDistanceFromLineMm", s.collinearPointsMaxDistanceFromLineMm, 0.0, 100.0);
  if (s.minThetaDegrees > s.maxThetaDegrees)
    e.fail("MinThetaDegrees {} is above MaxThetaDegrees {}", s.minThetaDegrees, s.maxThetaDegrees);
  if (auto v = e.ints<2>("ClipRectangleOrigin")) s.clipRectangleOrigin = {(*v)[0], (*v)[1]};
  if (auto v = e.ints<2>("ClipRectangleSize")) s.clipRectangleSize = {(*v)[0], (*v)[1]};
  if (s.clipRectangleOrigin.x < 0 || s.clipRectangleOrigin.y < 0 || s.clipRectangleSize.x < 0 ||
      s.clipRectangleSize.y < 0)
    e.fail("ClipRectangleOrigin and ClipRectangleSize must not be negative");
  if (auto v = e.choice<bool>("UseOriginalImageIntensityForDotIntensityScore", {{"TRUE", true}, {"FALSE", false}},
                              "TRUE, FALSE"))
    s.useOriginalImageIntensityForDotIntensityScore = *v;
  if (auto v = e.integer("NumberOfMaximumFiducialPointCandidates")) {
    if (*v < 3 || *v > 1000) e.fail("NumberOfMaximumFiducialPointCandidates {} is not in [3, 1000]", *v);
    s.numberOfMaximumFiducialPointCandidates = *v;
  }
  return s;
}

// An N: three coplanar wires, the outer two parallel, the middle one running
// from one outer wire's side to the other's (so the image plane cuts it
// between them).
void checkNWire(const ElementReader& e, const PlusNWirePattern& p) {
  const Vec3 d0 = p.wires[0].back - p.wires[0].front;
  const Vec3 d1 = p.wires[1].back - p.wires[1].front;
  const Vec3 d2 = p.wires[2].back - p.wires[2].front;
  for (const auto& w : p.wires)
    if (glm::length(w.back - w.front) < 1e-6) e.fail("wire {} has the same front and back end point", w.name);
  const Vec3 u0 = glm::normalize(d0), u2 = glm::normalize(d2);
  if (glm::length(glm::cross(u0, u2)) > std::sin(1.0 * 3.14159265358979 / 180.0))
    e.fail("the outer wires {} and {} are not parallel (an N-wire pattern needs them so)", p.wires[0].name,
           p.wires[2].name);
  const Vec3 across = p.wires[2].front - p.wires[0].front;
  const Vec3 normal = glm::cross(u0, across);
  if (glm::length(normal) < 1e-6) e.fail("the outer wires {} and {} lie on one line", p.wires[0].name, p.wires[2].name);
  const Vec3 nrm = glm::normalize(normal);
  for (const auto& w : p.wires)
    for (const Vec3& q : {w.front, w.back})
      if (std::abs(glm::dot(q - p.wires[0].front, nrm)) > 0.01)
        e.fail("wire {} is not in the plane of the outer wires (an N-wire pattern is flat)", w.name);
  if (glm::length(glm::cross(glm::normalize(d1), u0)) < std::sin(1.0 * 3.14159265358979 / 180.0))
    e.fail("the middle wire {} is parallel to the outer ones: it must run diagonally between them", p.wires[1].name);
  // Where the middle wire's ends lie across the pattern (0 at wire 0, 1 at wire 2).
  const Vec3 perp = glm::normalize(across - glm::dot(across, u0) * u0);
  const double width = glm::dot(across, perp);
  for (const Vec3& q : {p.wires[1].front, p.wires[1].back}) {
    const double t = glm::dot(q - p.wires[0].front, perp) / width;
    if (t < -1e-6 || t > 1.0 + 1e-6)
      e.fail("the middle wire {} leaves the strip between the outer wires {} and {}", p.wires[1].name,
             p.wires[0].name, p.wires[2].name);
  }
}

PlusPhantomDefinition readPhantomDefinition(const XmlFile& f, pugi::xml_node n) {
  PlusPhantomDefinition def;
  if (const pugi::xml_node d = n.child("Description")) {
    def.name = d.attribute("Name").value();
    def.version = d.attribute("Version").value();
  }
  const pugi::xml_node geometry = n.child("Geometry");
  if (!geometry) failAt(f, n, "PhantomDefinition: no Geometry element");
  int index = 0;
  for (const pugi::xml_node& pat : geometry.children()) {
    // PLUS writes <Pattern Type="NWire">; its older configs <NWire>.
    const bool pattern = std::strcmp(pat.name(), "Pattern") == 0;
    if (!pattern && std::strcmp(pat.name(), "NWire") != 0) continue;
    ++index;
    ElementReader pe(f, pat, fmt::format("PhantomDefinition: Pattern {}", index));
    if (pattern) {
      const auto type = pe.string("Type");
      if (!type) pe.fail("Type is missing");
      if (!equalsNoCase(trim(*type), "NWire"))
        pe.fail("Type '{}' is not supported: pp5echo calibrates with N-wire patterns (Type=\"NWire\")", *type);
    }
    PlusNWirePattern p;
    int w = 0;
    for (const pugi::xml_node& wire : pat.children("Wire")) {
      ElementReader we(f, wire, fmt::format("PhantomDefinition: Pattern {} Wire {}", index, w + 1));
      if (w >= 3) pe.fail("has more than 3 wires; an N-wire pattern has 3");
      const auto front = we.doubles<3>("EndPointFront");
      const auto back = we.doubles<3>("EndPointBack");
      if (!front) we.fail("EndPointFront is missing");
      if (!back) we.fail("EndPointBack is missing");
      p.wires[w].name = we.string("Name").value_or(fmt::format("{}", 3 * (index - 1) + w + 1));
      p.wires[w].front = Vec3((*front)[0], (*front)[1], (*front)[2]);
      p.wires[w].back = Vec3((*back)[0], (*back)[1], (*back)[2]);
      ++w;
    }
    if (w != 3) pe.fail("has {} wires; an N-wire pattern has 3", w);
    checkNWire(pe, p);
    def.patterns.push_back(p);
  }
  if (def.patterns.empty()) failAt(f, geometry, "PhantomDefinition: Geometry has no Pattern");
  return def;
}

}  // namespace pp5::plusxml
