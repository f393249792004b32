// The final reconstruction as files: three orthogonal slices (run.mpr) and
// the volume itself (run.volume, volume.mha).
#include <filesystem>
#include <memory>

#include "formats/volume_io.hpp"
#include "host/run_loop.hpp"
#include "outputs/slices.hpp"

namespace pp5::outputs {

namespace {

namespace fs = std::filesystem;

class VolumeFilesSink final : public host::Sink {
public:
  explicit VolumeFilesSink(const host::RunJob& j) : j_(j) {}
  bool wantsFinalVolume() const override { return true; }
  void finalVolume(const Volume& v) override {
    if (j_.mpr)
      for (const auto& p : host::writeMpr(v, j_.mprLook, (fs::path(j_.outDir) / "mpr").string()))
        wrote_.push_back(fs::path(p).filename().string());
    if (j_.volume) {
      writeVolume((fs::path(j_.outDir) / "volume.mha").string(), v.as(ScalarType::U8), true);
      wrote_.push_back("volume.mha");
    }
  }
  std::vector<std::string> wrote() const override { return wrote_; }

private:
  const host::RunJob& j_;
  std::vector<std::string> wrote_;
};

}  // namespace

std::unique_ptr<host::Sink> makeVolumeFilesSink(const host::RunJob& job) {
  if (!job.mpr && !job.volume) return nullptr;
  return std::make_unique<VolumeFilesSink>(job);
}

}  // namespace pp5::outputs
