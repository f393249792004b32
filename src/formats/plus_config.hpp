#pragma once
// PLUS device-set configuration XML (PlusConfiguration): CoordinateDefinitions
// and the VolumeReconstruction element. Reading uses pugixml; errors are
// InputError naming the file and the element or attribute.
#include <array>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <glm/glm.hpp>

#include "core/transform.hpp"

namespace pp5 {

enum class PlusInterpolation { NearestNeighbor, Linear };
enum class PlusCompounding { Mean, Latest, Maximum, ImportanceMask };
enum class PlusOptimization { None, Partial, Full, GpuAcceleratedOpenCL };
enum class PlusHoleFillingType {
  Gaussian,
  GaussianAccumulation,
  Stick,
  NearestNeighbor,
  DistanceWeightInverse,
};

// One <HoleFillingElement>. PLUS has no defaults here: Type is required, and
// so is each parameter that the type uses (GAUSSIAN, GAUSSIAN_ACCUMULATION:
// Size, Stdev, MinimumKnownVoxelsRatio; NEAREST_NEIGHBOR, DISTANCE_WEIGHT_INVERSE:
// Size, MinimumKnownVoxelsRatio; STICK: StickLengthLimit, NumberOfSticksToUse).
// The values below only fill the fields a type does not use.
struct PlusHoleFillingElement {
  PlusHoleFillingType type = PlusHoleFillingType::Gaussian;
  int size = 3;              // Size (odd kernel width in voxels)
  double stdev = 1.0;        // Stdev
  double minRatio = 0.5;     // MinimumKnownVoxelsRatio, 0..1
  int stickLengthLimit = 9;  // StickLengthLimit
  int numberOfSticksToUse = 1;  // NumberOfSticksToUse
  bool operator==(const PlusHoleFillingElement&) const = default;
};

// Every attribute of <VolumeReconstruction> that PLUS reads
// (vtkPlusVolumeReconstructor / vtkIGSIOVolumeReconstructor::ReadConfiguration).
// Optional fields are empty when the attribute is absent, so callers can tell
// "not given" from a default; PLUS's value for "not given" is in the comment.
// Deprecated PLUS spellings are read too and land in the same field: FanAngles
// (-> FanAnglesDeg), FanOrigin (-> FanOriginPixel), FanDepth (-> FanRadiusStopPixel),
// Compounding="ON|OFF" and Calculation="WEIGHTED_AVERAGE|MAXIMUM" (-> CompoundingMode
// when that is absent). Enumerated values are matched case-insensitively, as PLUS does.
struct PlusVolumeReconstruction {
  std::string imageCoordinateFrame = "Image";          // ImageCoordinateFrame
  std::string referenceCoordinateFrame = "Reference";  // ReferenceCoordinateFrame
  Vec3 outputSpacing{1.0};                         // OutputSpacing (required by PLUS), > 0
  std::optional<Vec3> outputOrigin;                // OutputOrigin (PLUS: fit to the frames)
  std::optional<std::array<int, 6>> outputExtent;  // OutputExtent x0 x1 y0 y1 z0 z1 (inclusive voxel indices)
  std::optional<glm::ivec2> clipRectangleOrigin;   // ClipRectangleOrigin (PLUS: 0 0)
  std::optional<glm::ivec2> clipRectangleSize;     // ClipRectangleSize (PLUS: 0 0 = whole frame)
  std::optional<glm::dvec2> fanAnglesDeg;          // FanAnglesDeg (min max), degrees (PLUS: 0 0 = no fan)
  std::optional<glm::dvec2> fanOriginPixel;        // FanOriginPixel (PLUS: 0 0)
  std::optional<double> fanRadiusStartPixel;       // FanRadiusStartPixel (PLUS: 0)
  std::optional<double> fanRadiusStopPixel;        // FanRadiusStopPixel (PLUS: 500)
  bool enableFanAnglesAutoDetect = false;          // EnableFanAnglesAutoDetect TRUE|FALSE
  double fanAnglesAutoDetectBrightnessThreshold = 30.0;  // FanAnglesAutoDetectBrightnessThreshold
  int fanAnglesAutoDetectFilterRadiusPixel = 10;         // FanAnglesAutoDetectFilterRadiusPixel
  int skipInterval = 1;                            // SkipInterval, >= 1
  PlusInterpolation interpolation = PlusInterpolation::NearestNeighbor;  // Interpolation
  PlusCompounding compounding = PlusCompounding::Mean;  // CompoundingMode (or legacy Compounding / Calculation)
  PlusOptimization optimization = PlusOptimization::Full;  // Optimization
  int numberOfThreads = 0;                         // NumberOfThreads, 0 = automatic
  bool fillHoles = false;                          // FillHoles ON|OFF
  std::optional<double> pixelRejectionThreshold;   // PixelRejectionThreshold (PLUS: disabled)
  std::string importanceMaskFile;                  // ImportanceMaskFilename; required for IMPORTANCE_MASK
  std::vector<PlusHoleFillingElement> holeFilling; // <HoleFilling><HoleFillingElement .../>; required if FillHoles
  bool operator==(const PlusVolumeReconstruction&) const = default;
};

// The spelling PLUS writes for each value (Optimization GPU is "OPENCL").
std::string_view toPlusString(PlusInterpolation v);
std::string_view toPlusString(PlusCompounding v);
std::string_view toPlusString(PlusOptimization v);
std::string_view toPlusString(PlusHoleFillingType v);

// One <Transform From=... To=... Matrix=.../> of <CoordinateDefinitions>.
struct PlusConfigTransform {
  std::string from, to;
  Mat4 matrix{1.0};
  bool operator==(const PlusConfigTransform&) const = default;
};

// One wire of a <PhantomDefinition><Geometry><Pattern>: a straight segment in
// the Phantom frame, mm.
struct PlusWire {
  std::string name;  // Name, e.g. "8:L1_h1"
  Vec3 front{0.0}, back{0.0};  // EndPointFront, EndPointBack
  bool operator==(const PlusWire&) const = default;
};

// An N-wire pattern: two parallel outer wires and a diagonal one between them,
// in one plane (PLUS's Pattern Type="NWire"), wires in file order.
struct PlusNWirePattern {
  std::array<PlusWire, 3> wires;
  bool operator==(const PlusNWirePattern&) const = default;
};

// <PhantomDefinition>: the calibration phantom's wires (fCal's multi-N).
struct PlusPhantomDefinition {
  std::string name, version;  // Description Name / Version
  std::vector<PlusNWirePattern> patterns;
  bool operator==(const PlusPhantomDefinition&) const = default;
};

// <Segmentation>: how fCal finds the wire dots. Every attribute PLUS's
// segmentation reads; the values are PLUS's own defaults where the attribute
// is optional (ApproximateSpacingMmPerPixel, the clip rectangle and the
// thresholds are required by PLUS, and by us).
struct PlusSegmentation {
  double approximateSpacingMmPerPixel = 0.0;      // ApproximateSpacingMmPerPixel, > 0
  double morphologicalOpeningCircleRadiusMm = 0.27;  // MorphologicalOpeningCircleRadiusMm
  double morphologicalOpeningBarSizeMm = 2.0;     // MorphologicalOpeningBarSizeMm
  glm::ivec2 clipRectangleOrigin{0, 0};           // ClipRectangleOrigin (pixels)
  glm::ivec2 clipRectangleSize{0, 0};             // ClipRectangleSize (pixels, 0 0 = whole frame)
  double maxLinePairDistanceErrorPercent = 10.0;  // MaxLinePairDistanceErrorPercent
  double angleToleranceDegrees = 10.0;            // AngleToleranceDegrees
  double maxAngleDifferenceDegrees = 10.0;        // MaxAngleDifferenceDegrees
  double minThetaDegrees = -70.0;                 // MinThetaDegrees
  double maxThetaDegrees = 70.0;                  // MaxThetaDegrees
  double maxLineShiftMm = 10.0;                   // MaxLineShiftMm
  double thresholdImagePercent = 10.0;            // ThresholdImagePercent, 0..100
  double collinearPointsMaxDistanceFromLineMm = 0.6;  // CollinearPointsMaxDistanceFromLineMm
  bool useOriginalImageIntensityForDotIntensityScore = false;  // UseOriginalImageIntensityForDotIntensityScore
  int numberOfMaximumFiducialPointCandidates = 20;  // NumberOfMaximumFiducialPointCandidates, >= 3
  bool operator==(const PlusSegmentation&) const = default;
};

// <vtkPlusProbeCalibrationAlgo>: the coordinate frames of a probe calibration.
struct PlusProbeCalibrationFrames {
  std::string image = "Image", probe = "Probe", phantom = "Phantom", reference = "Reference";
  bool operator==(const PlusProbeCalibrationFrames&) const = default;
};

struct PlusConfig {
  std::string path;
  TransformRepository coordinates;  // from <CoordinateDefinitions>
  std::vector<PlusConfigTransform> transforms;  // the same, as written, in file order
  std::optional<PlusVolumeReconstruction> volumeReconstruction;  // first one found anywhere
  std::string deviceSetName;         // DataCollection/DeviceSet Name, if any
  std::string deviceSetDescription;  // DataCollection/DeviceSet Description, if any
  // Probe calibration (fCal): present when the config has the element.
  std::optional<PlusPhantomDefinition> phantomDefinition;  // <PhantomDefinition>
  std::optional<PlusSegmentation> segmentation;            // <Segmentation>
  PlusProbeCalibrationFrames probeCalibrationFrames;       // <vtkPlusProbeCalibrationAlgo> (defaults without)
  // Why <PhantomDefinition> or <Segmentation> could not be read (both are then
  // empty): only a calibration needs them, so reading the config goes on.
  std::string calibrationError;

  // ImageToReference needs per-frame transforms from the sequence (e.g.
  // ProbeToTracker, ReferenceToTracker) plus the fixed ones here. Given the
  // names of the per-frame transforms a sequence provides, returns the shortest
  // chain of frames from Image to Reference (the VolumeReconstruction's
  // ImageCoordinateFrame / ReferenceCoordinateFrame) and which per-frame
  // transforms it uses. A sequence transform replaces a config one between the
  // same two frames, as in PLUS. Names that do not split into AToB are skipped.
  // Throws InputError naming the file, the sequence's transforms and the known
  // frames when Image cannot reach Reference.
  struct ChainPlan {
    std::vector<std::string> frames;  // Image ... Reference
    // The per-frame transforms the chain uses, as named by the sequence
    // ("ProbeToTracker", ...), in chain order. Each frame must carry them (valid).
    std::vector<std::string> perFrameTransforms;
  };
  ChainPlan planImageToReference(const std::vector<std::string>& perFrameTransformNames) const;

  // ImageCoordinateFrame / ReferenceCoordinateFrame of the VolumeReconstruction
  // element, or "Image" / "Reference" without one.
  std::string imageFrame() const;
  std::string referenceFrame() const;
};

// Reads a PLUS device-set configuration. Throws InputError naming the file (and
// line) on unreadable or malformed XML, a bad Matrix, or a bad attribute value.
PlusConfig readPlusConfig(const std::string& path);

// Writes a minimal PLUS 2.1 device-set config: DataCollection/DeviceSet
// (Name "pp5echo", Description `description`), CoordinateDefinitions (each
// transform From/To/Matrix, row-major) and a top-level VolumeReconstruction
// element (optional attributes only when set). Numbers are written with
// enough digits to read back exactly. The file is replaced atomically (written
// beside it, then renamed); throws InputError when it cannot be written.
void writePlusConfig(const std::string& path, const std::vector<PlusConfigTransform>& transforms,
                     const PlusVolumeReconstruction& recon, const std::string& description);

// Writes a copy of the config at `sourcePath` to `path` with one transform of
// <CoordinateDefinitions> set: any transform between the same two frames (in
// either direction) is removed, and <Transform From To Matrix Error Date/> is
// added as PLUS writes a calibration (Error in mm, Date as "mmddyy_hhmmss").
// Everything else is kept as it was. The file is replaced atomically; throws
// InputError when the source cannot be read or the result cannot be written.
void writePlusConfigWithTransform(const std::string& sourcePath, const std::string& path,
                                  const PlusConfigTransform& transform, double errorMm, const std::string& date);

// The per-frame ImageToReference for a frame, combining the config's fixed
// transforms with the frame's own tracked ones (through a TransformRepository).
// nullopt when a needed per-frame transform is missing or INVALID.
struct Frame;
std::optional<Mat4> imageToReference(const PlusConfig& cfg, const Frame& f);

}  // namespace pp5
