#include "formats/plus_config.hpp"
#include "formats/plus_xml.hpp"
#include "core/threads.hpp"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <map>
#include <sstream>
#include <system_error>
#include <utility>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <pugixml.hpp>
#include <spdlog/spdlog.h>

#include "core/error.hpp"
#include "core/io_util.hpp"
#include "core/frame.hpp"

// Attribute names, legal values and defaults follow PLUS's readers:
// vtkPlusVolumeReconstructor::ReadConfiguration (PlusLib), its successor
// vtkIGSIOVolumeReconstructor::ReadConfiguration (IGSIO),
// vtkIGSIOFillHolesInVolume::ReadConfiguration for the HoleFilling children, and
// the PLUS user manual page "Volume reconstruction algorithm". Where PLUS only logs
// a warning for a bad value and carries on with a default, we stop with an
// InputError instead: a silently ignored setting gives a wrong volume.

namespace pp5 {

using namespace plusxml;

std::string_view toPlusString(PlusInterpolation v) {
  switch (v) {
    case PlusInterpolation::NearestNeighbor: return "NEAREST_NEIGHBOR";
    case PlusInterpolation::Linear: return "LINEAR";
  }
  return "?";
}

std::string_view toPlusString(PlusCompounding v) {
  switch (v) {
    case PlusCompounding::Mean: return "MEAN";
    case PlusCompounding::Latest: return "LATEST";
    case PlusCompounding::Maximum: return "MAXIMUM";
    case PlusCompounding::ImportanceMask: return "IMPORTANCE_MASK";
  }
  return "?";
}

std::string_view toPlusString(PlusOptimization v) {
  switch (v) {
    case PlusOptimization::None: return "NONE";
    case PlusOptimization::Partial: return "PARTIAL";
    case PlusOptimization::Full: return "FULL";
    case PlusOptimization::GpuAcceleratedOpenCL: return "OPENCL";
  }
  return "?";
}

std::string_view toPlusString(PlusHoleFillingType v) {
  switch (v) {
    case PlusHoleFillingType::Gaussian: return "GAUSSIAN";
    case PlusHoleFillingType::GaussianAccumulation: return "GAUSSIAN_ACCUMULATION";
    case PlusHoleFillingType::Stick: return "STICK";
    case PlusHoleFillingType::NearestNeighbor: return "NEAREST_NEIGHBOR";
    case PlusHoleFillingType::DistanceWeightInverse: return "DISTANCE_WEIGHT_INVERSE";
  }
  return "?";
}

namespace {
PlusHoleFillingElement readHoleFillingElement(const XmlFile& f, pugi::xml_node n, int index) {
  ElementReader e(f, n, fmt::format("HoleFillingElement #{}", index));
  PlusHoleFillingElement h;
  const auto type = e.choice<PlusHoleFillingType>(
      "Type",
      {{"GAUSSIAN", PlusHoleFillingType::Gaussian},
       {"GAUSSIAN_ACCUMULATION", PlusHoleFillingType::GaussianAccumulation},
       {"STICK", PlusHoleFillingType::Stick},
       {"NEAREST_NEIGHBOR", PlusHoleFillingType::NearestNeighbor},
       {"DISTANCE_WEIGHT_INVERSE", PlusHoleFillingType::DistanceWeightInverse}},
      "GAUSSIAN, GAUSSIAN_ACCUMULATION, STICK, NEAREST_NEIGHBOR, DISTANCE_WEIGHT_INVERSE");
  if (!type) e.fail("Type is missing");
  h.type = *type;

  // Parameters a type does not use are still read when present, so that the
  // struct says what the file says; the ones it uses are required, as in PLUS.
  const bool gaussian = h.type == PlusHoleFillingType::Gaussian || h.type == PlusHoleFillingType::GaussianAccumulation;
  const bool stick = h.type == PlusHoleFillingType::Stick;
  auto require = [&](const char* attr, bool needed) {
    if (needed && !e.has(attr)) e.fail("{} is missing (Type {} needs it)", attr, toPlusString(h.type));
  };
  require("Size", !stick);
  require("MinimumKnownVoxelsRatio", !stick);
  require("Stdev", gaussian);
  require("StickLengthLimit", stick);
  require("NumberOfSticksToUse", stick);

  if (auto v = e.integer("Size")) {
    if (*v < 1 || *v % 2 == 0) e.fail("Size '{}' must be a positive odd number", *v);
    h.size = *v;
  }
  if (auto v = e.real("Stdev")) {
    if (!(*v > 0.0)) e.fail("Stdev '{}' must be positive", *v);
    h.stdev = *v;
  }
  if (auto v = e.real("MinimumKnownVoxelsRatio")) {
    if (*v < 0.0 || *v > 1.0) e.fail("MinimumKnownVoxelsRatio '{}' must lie in [0, 1]", *v);
    h.minRatio = *v;
  }
  if (auto v = e.integer("StickLengthLimit")) {
    if (*v < 1) e.fail("StickLengthLimit '{}' must be at least 1", *v);
    h.stickLengthLimit = *v;
  }
  if (auto v = e.integer("NumberOfSticksToUse")) {
    if (*v < 1) e.fail("NumberOfSticksToUse '{}' must be at least 1", *v);
    h.numberOfSticksToUse = *v;
  }
  return h;
}

PlusVolumeReconstruction readVolumeReconstruction(const XmlFile& f, pugi::xml_node n) {
  ElementReader e(f, n, "VolumeReconstruction");
  e.warnUnknown({"ImageCoordinateFrame", "ReferenceCoordinateFrame", "OutputSpacing", "OutputOrigin", "OutputExtent",
                 "ClipRectangleOrigin", "ClipRectangleSize", "FanAngles", "FanAnglesDeg", "FanOrigin", "FanOriginPixel",
                 "FanDepth", "FanRadiusStartPixel", "FanRadiusStopPixel", "FanAnglesAutoDetectBrightnessThreshold",
                 "FanAnglesAutoDetectFilterRadiusPixel", "EnableFanAnglesAutoDetect", "PixelRejectionThreshold",
                 "SkipInterval", "Interpolation", "Optimization", "CompoundingMode", "Compounding", "Calculation",
                 "NumberOfThreads", "ImportanceMaskFilename", "FillHoles"});
  PlusVolumeReconstruction r;

  if (auto v = e.name("ImageCoordinateFrame")) r.imageCoordinateFrame = *v;
  if (auto v = e.name("ReferenceCoordinateFrame")) r.referenceCoordinateFrame = *v;
  if (r.imageCoordinateFrame == r.referenceCoordinateFrame)
    e.fail("ImageCoordinateFrame and ReferenceCoordinateFrame are both '{}'", r.imageCoordinateFrame);

  const auto spacing = e.doubles<3>("OutputSpacing");
  if (!spacing) e.fail("OutputSpacing is missing (PLUS requires it)");
  for (double s : *spacing)
    if (!(s > 0.0)) e.fail("OutputSpacing '{} {} {}' must be positive", (*spacing)[0], (*spacing)[1], (*spacing)[2]);
  r.outputSpacing = Vec3((*spacing)[0], (*spacing)[1], (*spacing)[2]);
  if (auto v = e.doubles<3>("OutputOrigin")) r.outputOrigin = Vec3((*v)[0], (*v)[1], (*v)[2]);
  if (auto v = e.ints<6>("OutputExtent")) {
    for (int a = 0; a < 3; ++a)
      if ((*v)[2 * a] > (*v)[2 * a + 1])
        e.fail("OutputExtent '{}': axis {} ends ({}) before it starts ({})", fmt::join(*v, " "), "xyz"[a],
               (*v)[2 * a + 1], (*v)[2 * a]);
    r.outputExtent = *v;
  }

  if (auto v = e.ints<2>("ClipRectangleOrigin")) r.clipRectangleOrigin = glm::ivec2((*v)[0], (*v)[1]);
  if (auto v = e.ints<2>("ClipRectangleSize")) {
    if ((*v)[0] < 0 || (*v)[1] < 0) e.fail("ClipRectangleSize '{} {}' must not be negative", (*v)[0], (*v)[1]);
    r.clipRectangleSize = glm::ivec2((*v)[0], (*v)[1]);
  }

  // PLUS reads the deprecated spelling first, so the current one wins when both are given.
  for (const char* attr : {"FanAngles", "FanAnglesDeg"})
    if (auto v = e.doubles<2>(attr)) {
      if (std::abs((*v)[0]) > 180.0 || std::abs((*v)[1]) > 180.0)
        e.fail("{} '{} {}' must lie in -180 .. 180 degrees", attr, (*v)[0], (*v)[1]);
      r.fanAnglesDeg = glm::dvec2((*v)[0], (*v)[1]);
    }
  for (const char* attr : {"FanOrigin", "FanOriginPixel"})
    if (auto v = e.doubles<2>(attr)) r.fanOriginPixel = glm::dvec2((*v)[0], (*v)[1]);
  if (auto v = e.real("FanRadiusStartPixel")) {
    if (*v < 0.0) e.fail("FanRadiusStartPixel '{}' must not be negative", *v);
    r.fanRadiusStartPixel = *v;
  }
  for (const char* attr : {"FanDepth", "FanRadiusStopPixel"})
    if (auto v = e.real(attr)) {
      if (*v < 0.0) e.fail("{} '{}' must not be negative", attr, *v);
      r.fanRadiusStopPixel = *v;
    }
  // (PLUS's defaults: start 0, stop 500.)
  if (r.fanRadiusStartPixel.value_or(0.0) > r.fanRadiusStopPixel.value_or(500.0))
    e.fail("FanRadiusStartPixel '{}' lies beyond the fan's stop radius '{}': no pixel would be kept",
           r.fanRadiusStartPixel.value_or(0.0), r.fanRadiusStopPixel.value_or(500.0));
  if (auto v = e.real("FanAnglesAutoDetectBrightnessThreshold")) r.fanAnglesAutoDetectBrightnessThreshold = *v;
  if (auto v = e.integer("FanAnglesAutoDetectFilterRadiusPixel")) {
    if (*v < 1) e.fail("FanAnglesAutoDetectFilterRadiusPixel '{}' must be at least 1", *v);
    r.fanAnglesAutoDetectFilterRadiusPixel = *v;
  }
  if (auto v = e.choice<bool>("EnableFanAnglesAutoDetect", {{"TRUE", true}, {"FALSE", false}}, "TRUE, FALSE"))
    r.enableFanAnglesAutoDetect = *v;

  if (auto v = e.real("PixelRejectionThreshold")) r.pixelRejectionThreshold = *v;
  if (auto v = e.integer("SkipInterval")) {
    // PLUS resets a value below 1 to 1 with a warning; a typo here should not pass quietly.
    if (*v < 1) e.fail("SkipInterval '{}' must be at least 1", *v);
    r.skipInterval = *v;
  }

  if (auto v = e.choice<PlusInterpolation>(
          "Interpolation",
          {{"NEAREST_NEIGHBOR", PlusInterpolation::NearestNeighbor}, {"LINEAR", PlusInterpolation::Linear}},
          "NEAREST_NEIGHBOR, LINEAR"))
    r.interpolation = *v;
  // IGSIO spells the GPU mode "OPENCL"; GPU_ACCELERATION_OPENCL is its enum name.
  if (auto v = e.choice<PlusOptimization>("Optimization",
                                          {{"NONE", PlusOptimization::None},
                                           {"PARTIAL", PlusOptimization::Partial},
                                           {"FULL", PlusOptimization::Full},
                                           {"OPENCL", PlusOptimization::GpuAcceleratedOpenCL},
                                           {"GPU_ACCELERATION_OPENCL", PlusOptimization::GpuAcceleratedOpenCL}},
                                          "NONE, PARTIAL, FULL, OPENCL"))
    r.optimization = *v;

  // Older PlusLib wrote IMPORTANCEMASK; IGSIO writes IMPORTANCE_MASK.
  const auto mode = e.choice<PlusCompounding>("CompoundingMode",
                                              {{"MEAN", PlusCompounding::Mean},
                                               {"LATEST", PlusCompounding::Latest},
                                               {"MAXIMUM", PlusCompounding::Maximum},
                                               {"IMPORTANCE_MASK", PlusCompounding::ImportanceMask},
                                               {"IMPORTANCEMASK", PlusCompounding::ImportanceMask}},
                                              "MEAN, LATEST, MAXIMUM, IMPORTANCE_MASK");
  // Deprecated since 2014 but still in old configs (e.g. Compounding="On"). PLUS
  // uses them only when CompoundingMode is absent: Calculation=MAXIMUM gives
  // MAXIMUM, else Compounding=OFF gives LATEST, else MEAN.
  const auto legacyOn = e.choice<bool>("Compounding", {{"ON", true}, {"OFF", false}}, "ON, OFF");
  enum class Calc { WeightedAverage, Maximum };
  const auto legacyCalc = e.choice<Calc>(
      "Calculation", {{"WEIGHTED_AVERAGE", Calc::WeightedAverage}, {"MAXIMUM", Calc::Maximum}},
      "WEIGHTED_AVERAGE, MAXIMUM");
  if (mode) r.compounding = *mode;
  else if (legacyCalc == Calc::Maximum) r.compounding = PlusCompounding::Maximum;
  else if (legacyOn == false) r.compounding = PlusCompounding::Latest;
  else r.compounding = PlusCompounding::Mean;

  if (auto v = e.integer("NumberOfThreads")) {
    if (*v < 0 || *v > kMaxThreads)
      e.fail("NumberOfThreads '{}' must be in 0 .. {} (0 means automatic)", *v, kMaxThreads);
    r.numberOfThreads = *v;
  }
  if (auto v = e.name("ImportanceMaskFilename")) r.importanceMaskFile = *v;
  if (r.compounding == PlusCompounding::ImportanceMask && r.importanceMaskFile.empty())
    e.fail("ImportanceMaskFilename is missing (CompoundingMode IMPORTANCE_MASK needs it)");

  if (auto v = e.choice<bool>("FillHoles", {{"ON", true}, {"OFF", false}}, "ON, OFF")) r.fillHoles = *v;

  // PLUS reads HoleFilling only when FillHoles is ON; we read it whenever it is
  // there, so that a written config reads back the same.
  const pugi::xml_node hf = n.child("HoleFilling");
  if (r.fillHoles && !hf) e.fail("FillHoles is ON but there is no HoleFilling element");
  if (hf) {
    int index = 0;
    for (const pugi::xml_node& c : hf.children()) {
      if (c.type() != pugi::node_element || !equalsNoCase(c.name(), "HoleFillingElement")) continue;
      r.holeFilling.push_back(readHoleFillingElement(f, c, ++index));
    }
  }
  return r;
}

void readCoordinateDefinitions(const XmlFile& f, pugi::xml_node root, PlusConfig& cfg) {
  // PLUS looks only at the first CoordinateDefinitions directly under the root.
  const pugi::xml_node defs = root.child("CoordinateDefinitions");
  if (!defs) return;
  for (const pugi::xml_node& t : defs.children("Transform")) {
    ElementReader e(f, t, "CoordinateDefinitions: Transform");
    // Other attributes (Error, Date, Persistent) describe the calibration and do
    // not change the matrix; Persistent="FALSE" transforms are used like the rest.
    const auto from = e.name("From");
    const auto to = e.name("To");
    if (!from) e.fail("From is missing");
    if (!to) e.fail("To is missing");
    const std::string label = fmt::format("CoordinateDefinitions: Transform {}To{}", *from, *to);
    ElementReader te(f, t, label);
    if (*from == *to) te.fail("From and To are the same frame");
    const char* text = te.raw("Matrix");
    if (!text) te.fail("Matrix is missing");
    std::string why;
    const auto m = parseRowMajor(text, &why);
    if (!m) te.fail("Matrix {}", why);
    for (const auto& prev : cfg.transforms)
      if ((prev.from == *from && prev.to == *to) || (prev.from == *to && prev.to == *from))
        te.fail("{}To{} is already defined", prev.from, prev.to);
    cfg.transforms.push_back({*from, *to, *m});
    cfg.coordinates.set(*from, *to, *m);
  }
}

std::string joinNames(const std::vector<std::string>& v) {
  if (v.empty()) return "none";
  std::string s;
  for (const auto& x : v) {
    if (!s.empty()) s += ", ";
    s += x;
  }
  return s;
}

std::string fmtNum(double x) { return fmt::format("{}", x); }

}  // namespace

std::string PlusConfig::imageFrame() const {
  return volumeReconstruction ? volumeReconstruction->imageCoordinateFrame : std::string("Image");
}

std::string PlusConfig::referenceFrame() const {
  return volumeReconstruction ? volumeReconstruction->referenceCoordinateFrame : std::string("Reference");
}

PlusConfig readPlusConfig(const std::string& path) {
  XmlFile f;
  f.path = path;
  loadXml(f);
  const pugi::xml_node root = f.doc.document_element();
  if (!root) inputError(path, "no XML element in the file");
  if (std::strcmp(root.name(), "PlusConfiguration") != 0)
    failAt(f, root, "root element is <{}>, expected <PlusConfiguration>", root.name());

  PlusConfig cfg;
  cfg.path = path;
  readCoordinateDefinitions(f, root, cfg);

  if (const pugi::xml_node ds = root.child("DataCollection").child("DeviceSet")) {
    cfg.deviceSetName = ds.attribute("Name").value();
    cfg.deviceSetDescription = ds.attribute("Description").value();
  }

  // The element sits at the top level in reconstruction-only configs and inside
  // DataCollection/Device (a VirtualVolumeReconstructor) in server configs.
  // One of them: a second would be ignored without a word.
  std::vector<pugi::xml_node> vrs;
  for (const pugi::xpath_node& x : root.select_nodes("//VolumeReconstruction")) vrs.push_back(x.node());
  if (vrs.size() > 1)
    failAt(f, vrs[1], "a second VolumeReconstruction element (the first is on line {}); pp5echo reconstructs with one: "
                      "keep the one to use",
           f.lineOf(vrs[0]));
  if (!vrs.empty()) cfg.volumeReconstruction = readVolumeReconstruction(f, vrs[0]);

  // The calibration's elements are read here but only a calibration needs
  // them: a problem in them is kept for `calibrate` to report, and does not
  // stop a reconstruction with the same config.
  try {
    if (const pugi::xml_node pd = root.child("PhantomDefinition")) cfg.phantomDefinition = readPhantomDefinition(f, pd);
    if (const pugi::xml_node seg = root.child("Segmentation")) cfg.segmentation = readSegmentation(f, seg);
  } catch (const InputError& e) {
    cfg.phantomDefinition.reset();
    cfg.segmentation.reset();
    cfg.calibrationError = e.what();
  }
  if (const pugi::xml_node pc = root.child("vtkPlusProbeCalibrationAlgo")) {
    ElementReader e(f, pc, "vtkPlusProbeCalibrationAlgo");
    auto& fr = cfg.probeCalibrationFrames;
    if (auto v = e.name("ImageCoordinateFrame")) fr.image = *v;
    if (auto v = e.name("ProbeCoordinateFrame")) fr.probe = *v;
    if (auto v = e.name("PhantomCoordinateFrame")) fr.phantom = *v;
    if (auto v = e.name("ReferenceCoordinateFrame")) fr.reference = *v;
  }
  return cfg;
}

void writePlusConfigWithTransform(const std::string& sourcePath, const std::string& path,
                                  const PlusConfigTransform& transform, double errorMm, const std::string& date) {
  PP5_CHECK(!transform.from.empty() && !transform.to.empty());
  PP5_CHECK(isFinite(transform.matrix));
  XmlFile f;
  f.path = sourcePath;
  loadXml(f);
  pugi::xml_node root = f.doc.document_element();
  if (!root || std::strcmp(root.name(), "PlusConfiguration") != 0)
    inputError(sourcePath, "root element is not <PlusConfiguration>");
  pugi::xml_node defs = root.child("CoordinateDefinitions");
  if (!defs) defs = root.prepend_child("CoordinateDefinitions");
  for (pugi::xml_node t = defs.child("Transform"); t;) {
    const pugi::xml_node next = t.next_sibling("Transform");
    const std::string from = std::string(trim(t.attribute("From").value()));
    const std::string to = std::string(trim(t.attribute("To").value()));
    if ((from == transform.from && to == transform.to) || (from == transform.to && to == transform.from))
      defs.remove_child(t);
    t = next;
  }
  pugi::xml_node x = defs.append_child("Transform");
  x.append_attribute("From") = transform.from.c_str();
  x.append_attribute("To") = transform.to.c_str();
  x.append_attribute("Matrix") = formatRowMajor(transform.matrix).c_str();
  x.append_attribute("Error") = fmt::format("{:.6g}", errorMm).c_str();
  x.append_attribute("Date") = date.c_str();
  std::ostringstream out;
  f.doc.save(out, "  ", pugi::format_default, pugi::encoding_utf8);
  io::AtomicFile file(path);
  file.write(out.str());
  file.commit();
}

PlusConfig::ChainPlan PlusConfig::planImageToReference(const std::vector<std::string>& perFrameTransformNames) const {
  TransformRepository repo = coordinates;
  // Per-frame transforms, keyed by their (unordered) pair of frames. A sequence
  // transform replaces a config one between the same frames, as in PLUS, where
  // each frame's transforms are set into the repository after the config's.
  std::map<std::pair<std::string, std::string>, std::string> perFrame;
  for (const auto& name : perFrameTransformNames) {
    const auto split = splitTransformName(name);
    if (!split || split->first == split->second) continue;  // cannot be a link of any chain
    repo.set(split->first, split->second, Mat4(1.0));
    perFrame[std::minmax(split->first, split->second)] = name;
  }
  const std::string img = imageFrame();
  const std::string ref = referenceFrame();
  ChainPlan plan;
  plan.frames = repo.path(img, ref);
  if (plan.frames.empty()) {
    auto known = repo.frames();
    std::sort(known.begin(), known.end());
    inputError(path,
               "no chain from {} to {} through CoordinateDefinitions and the sequence's transforms ({}); "
               "known frames: {}",
               img, ref, joinNames(perFrameTransformNames), joinNames(known));
  }
  for (std::size_t k = 0; k + 1 < plan.frames.size(); ++k) {
    const auto it = perFrame.find(std::minmax(plan.frames[k], plan.frames[k + 1]));
    if (it != perFrame.end()) plan.perFrameTransforms.push_back(it->second);
  }
  return plan;
}

std::optional<Mat4> imageToReference(const PlusConfig& cfg, const Frame& f) {
  TransformRepository repo = cfg.coordinates;
  for (const auto& t : f.transforms) {
    const auto split = splitTransformName(t.name);
    if (!split || split->first == split->second) continue;
    repo.set(split->first, split->second, t.matrix, t.valid);
  }
  auto m = repo.get(cfg.imageFrame(), cfg.referenceFrame());
  if (m && !isFinite(*m)) return std::nullopt;  // a singular link was inverted
  return m;
}

void writePlusConfig(const std::string& path, const std::vector<PlusConfigTransform>& transforms,
                     const PlusVolumeReconstruction& recon, const std::string& description) {
  pugi::xml_document doc;
  pugi::xml_node decl = doc.append_child(pugi::node_declaration);
  decl.append_attribute("version") = "1.0";
  decl.append_attribute("encoding") = "UTF-8";

  pugi::xml_node root = doc.append_child("PlusConfiguration");
  root.append_attribute("version") = "2.1";

  pugi::xml_node ds = root.append_child("DataCollection").append_child("DeviceSet");
  ds.append_attribute("Name") = "pp5echo";
  ds.append_attribute("Description") = description.c_str();

  pugi::xml_node defs = root.append_child("CoordinateDefinitions");
  for (const auto& t : transforms) {
    PP5_CHECK(!t.from.empty() && !t.to.empty());
    PP5_CHECK_NE(t.from, t.to);
    PP5_CHECK(isFinite(t.matrix));
    pugi::xml_node x = defs.append_child("Transform");
    x.append_attribute("From") = t.from.c_str();
    x.append_attribute("To") = t.to.c_str();
    x.append_attribute("Matrix") = formatRowMajor(t.matrix).c_str();
  }

  pugi::xml_node v = root.append_child("VolumeReconstruction");
  auto set = [&v](const char* name, const std::string& value) { v.append_attribute(name) = value.c_str(); };
  auto vec = [](auto... xs) {
    std::string s;
    ((s += (s.empty() ? "" : " ") + fmtNum(static_cast<double>(xs))), ...);
    return s;
  };
  set("ImageCoordinateFrame", recon.imageCoordinateFrame);
  set("ReferenceCoordinateFrame", recon.referenceCoordinateFrame);
  set("OutputSpacing", vec(recon.outputSpacing.x, recon.outputSpacing.y, recon.outputSpacing.z));
  if (recon.outputOrigin) set("OutputOrigin", vec(recon.outputOrigin->x, recon.outputOrigin->y, recon.outputOrigin->z));
  if (recon.outputExtent) set("OutputExtent", fmt::format("{}", fmt::join(*recon.outputExtent, " ")));
  if (recon.clipRectangleOrigin) set("ClipRectangleOrigin", vec(recon.clipRectangleOrigin->x, recon.clipRectangleOrigin->y));
  if (recon.clipRectangleSize) set("ClipRectangleSize", vec(recon.clipRectangleSize->x, recon.clipRectangleSize->y));
  if (recon.fanAnglesDeg) set("FanAnglesDeg", vec(recon.fanAnglesDeg->x, recon.fanAnglesDeg->y));
  if (recon.fanOriginPixel) set("FanOriginPixel", vec(recon.fanOriginPixel->x, recon.fanOriginPixel->y));
  if (recon.fanRadiusStartPixel) set("FanRadiusStartPixel", fmtNum(*recon.fanRadiusStartPixel));
  if (recon.fanRadiusStopPixel) set("FanRadiusStopPixel", fmtNum(*recon.fanRadiusStopPixel));
  set("EnableFanAnglesAutoDetect", recon.enableFanAnglesAutoDetect ? "TRUE" : "FALSE");
  set("FanAnglesAutoDetectBrightnessThreshold", fmtNum(recon.fanAnglesAutoDetectBrightnessThreshold));
  set("FanAnglesAutoDetectFilterRadiusPixel", std::to_string(recon.fanAnglesAutoDetectFilterRadiusPixel));
  if (recon.pixelRejectionThreshold) set("PixelRejectionThreshold", fmtNum(*recon.pixelRejectionThreshold));
  set("SkipInterval", std::to_string(recon.skipInterval));
  set("Interpolation", std::string(toPlusString(recon.interpolation)));
  set("Optimization", std::string(toPlusString(recon.optimization)));
  set("CompoundingMode", std::string(toPlusString(recon.compounding)));
  set("NumberOfThreads", std::to_string(recon.numberOfThreads));
  if (!recon.importanceMaskFile.empty()) set("ImportanceMaskFilename", recon.importanceMaskFile);
  set("FillHoles", recon.fillHoles ? "ON" : "OFF");
  if (!recon.holeFilling.empty()) {
    pugi::xml_node hf = v.append_child("HoleFilling");
    const PlusHoleFillingElement defaults;
    for (const auto& h : recon.holeFilling) {
      pugi::xml_node x = hf.append_child("HoleFillingElement");
      x.append_attribute("Type") = std::string(toPlusString(h.type)).c_str();
      const bool gaussian = h.type == PlusHoleFillingType::Gaussian || h.type == PlusHoleFillingType::GaussianAccumulation;
      const bool stick = h.type == PlusHoleFillingType::Stick;
      // The parameters the type uses, plus any other that differs from the
      // default (so the element reads back to the same struct).
      if (!stick || h.size != defaults.size) x.append_attribute("Size") = std::to_string(h.size).c_str();
      if (gaussian || h.stdev != defaults.stdev) x.append_attribute("Stdev") = fmtNum(h.stdev).c_str();
      if (!stick || h.minRatio != defaults.minRatio)
        x.append_attribute("MinimumKnownVoxelsRatio") = fmtNum(h.minRatio).c_str();
      if (stick || h.stickLengthLimit != defaults.stickLengthLimit)
        x.append_attribute("StickLengthLimit") = std::to_string(h.stickLengthLimit).c_str();
      if (stick || h.numberOfSticksToUse != defaults.numberOfSticksToUse)
        x.append_attribute("NumberOfSticksToUse") = std::to_string(h.numberOfSticksToUse).c_str();
    }
  }

  // Write beside the target and rename, so a failed write never leaves a
  // half-written config where a good one was.
  const std::string tmp = path + ".tmp";
  if (!doc.save_file(tmp.c_str(), "  ", pugi::format_default, pugi::encoding_utf8)) {
    const int err = errno;
    std::remove(tmp.c_str());
    inputError(path, "cannot write: {}", err ? std::strerror(err) : "unknown error");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const int err = errno;
    std::remove(tmp.c_str());
    inputError(path, "cannot write: {}", std::strerror(err));
  }
}

}  // namespace pp5
