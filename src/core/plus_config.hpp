#pragma once
// PLUS device-set configuration XML (PlusConfiguration): CoordinateDefinitions
// and the VolumeReconstruction element. Reading uses pugixml; errors are
// InputError naming the file and the element or attribute.
#include <optional>
#include <string>
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

struct PlusHoleFillingElement {
  PlusHoleFillingType type = PlusHoleFillingType::Gaussian;
  int size = 3;              // Size (kernel width in voxels)
  double stdev = 1.0;        // Stdev
  double minRatio = 0.5;     // MinRatio
  int stickLengthLimit = 9;  // StickLengthLimit
  int numberOfSticksToUse = 1;
};

// Every attribute of <VolumeReconstruction> in the PLUS documentation. Optional
// fields are empty when the attribute is absent, so callers can tell "not given"
// from a default.
struct PlusVolumeReconstruction {
  std::string imageCoordinateFrame = "Image";
  std::string referenceCoordinateFrame = "Reference";
  Vec3 outputSpacing{1.0};
  std::optional<Vec3> outputOrigin;
  std::optional<std::array<int, 6>> outputExtent;  // x0 x1 y0 y1 z0 z1 (inclusive voxel indices)
  std::optional<glm::ivec2> clipRectangleOrigin;
  std::optional<glm::ivec2> clipRectangleSize;
  std::optional<glm::dvec2> fanAnglesDeg;          // FanAngles (min max), degrees
  std::optional<glm::dvec2> fanOriginPixel;        // FanOrigin
  std::optional<double> fanRadiusStartPixel;       // FanRadiusStart
  std::optional<double> fanRadiusStopPixel;        // FanRadiusStop
  bool enableFanAnglesAutoDetect = false;          // EnableFanAnglesAutoDetect
  int skipInterval = 1;                            // SkipInterval
  PlusInterpolation interpolation = PlusInterpolation::NearestNeighbor;
  PlusCompounding compounding = PlusCompounding::Mean;  // CompoundingMode (or legacy Compounding="ON")
  PlusOptimization optimization = PlusOptimization::Full;
  int numberOfThreads = 0;                         // 0 = automatic
  bool fillHoles = false;                          // FillHoles
  std::optional<double> pixelRejectionThreshold;   // PixelRejectionThreshold
  std::string importanceMaskFile;                  // ImportanceMask (file name), for IMPORTANCE_MASK
  std::vector<PlusHoleFillingElement> holeFilling; // <HoleFilling><HoleFillingElement .../>
};

struct PlusConfig {
  std::string path;
  TransformRepository coordinates;  // from <CoordinateDefinitions>
  std::optional<PlusVolumeReconstruction> volumeReconstruction;  // first one found anywhere

  // ImageToReference needs per-frame transforms from the sequence (e.g.
  // ProbeToTracker, ReferenceToTracker) plus the fixed ones here. Given the
  // names of the per-frame transforms available, returns the static part of the
  // chain: ImageToX where X is the first frame on a path to Reference that the
  // sequence provides. Throws InputError naming the file when Image cannot reach
  // Reference through the config and the given frame names.
  struct ChainPlan {
    std::vector<std::string> frames;  // Image ... Reference
  };
  ChainPlan planImageToReference(const std::vector<std::string>& perFrameTransformNames) const;
};

PlusConfig readPlusConfig(const std::string& path);

// Writes a minimal device-set config: CoordinateDefinitions (each transform
// From/To/Matrix) and a VolumeReconstruction element.
struct PlusConfigTransform {
  std::string from, to;
  Mat4 matrix;
};
void writePlusConfig(const std::string& path, const std::vector<PlusConfigTransform>& transforms,
                     const PlusVolumeReconstruction& recon, const std::string& description);

// The per-frame ImageToReference for a frame, combining the config's fixed
// transforms with the frame's own tracked ones (through a TransformRepository).
// nullopt when a needed per-frame transform is missing or INVALID.
struct Frame;
std::optional<Mat4> imageToReference(const PlusConfig& cfg, const Frame& f);

}  // namespace pp5
