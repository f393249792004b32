// The distributed pipeline's requests and checks: an image composited in
// another mode, the reconstructed volume gathered from the graphics
// processors, and the comparison with the serial pipeline beside it.
#include <algorithm>
#include <cstring>

#include <fmt/format.h>

#include "core/error.hpp"
#include "host/distributed_pipeline.hpp"

namespace pp5::host {

using namespace pp5::comm;

// The image after the last update, compared with the serial pipeline's.
void DistributedPipeline::verify(const std::vector<float>& got, const pp::CompositeMode* mode,
                                 const std::string& what) {
  if (!ref_) return;
  const pp::TileImage& want = !mode || *mode == ref_->liveMode() ? ref_->image() : ref_->compositeFull(*mode);
  PP5_CHECK_EQ(want.rgba.size(), got.size());
  if (std::memcmp(got.data(), want.rgba.data(), got.size() * sizeof(float)) != 0) {
    for (std::size_t i = 0; i < got.size(); ++i)
      if (std::memcmp(&got[i], &want.rgba[i], sizeof(float)) != 0) {
        const std::size_t px = i / 4;
        throw InvariantError(fmt::format("{}: the distributed image differs from the serial pipeline's at pixel "
                                         "({}, {}) channel {}: {} against {}",
                                         what, px % static_cast<std::size_t>(w_), px / static_cast<std::size_t>(w_),
                                         i % 4, got[i], want.rgba[i]));
      }
  }
  ++verified_;
}

std::vector<float> DistributedPipeline::composite(pp::CompositeMode mode) {
  RequestMsg rq;
  rq.h = {kTagRequest, epoch_, sent_ ? sent_ - 1 : 0};
  rq.mode = static_cast<std::uint8_t>(mode);
  requestsDone_ = 0;
  std::fill(requestFb_.begin(), requestFb_.end(), 0.0f);
  for (int p = 0; p < L_.pps; ++p) t_.send(L_.ppRank(p), rq);
  waitUntil([&] { return requestsDone_ == L_.pps; }, fmt::format("the {} image", pp::compositeModeName(mode)));
  return requestFb_;
}

// ---- the volume --------------------------------------------------------

void DistributedPipeline::askVolume() {
  EmptyMsg rq;
  rq.h = {kTagVolumeRequest, epoch_, sent_ ? sent_ - 1 : 0};
  volumesDone_ = 0;
  volumeChange_ = VolumeChange{false, {}};
  for (int g = 0; g < L_.gps; ++g) t_.send(L_.gpRank(g), rq);
}

bool DistributedPipeline::requestVolume() {
  if (volumeOutstanding_ || sent_ == 0) return false;
  volumeOutstanding_ = true;
  askVolume();
  return true;
}

void DistributedPipeline::settle() {
  waitUntil([&] { return shownEpoch_ == epoch_ && !volumeOutstanding_; }, "the volume for the viewer's slices");
}

const Volume& DistributedPipeline::volume() {
  settle();
  askVolume();
  waitUntil([&] { return volumesDone_ == L_.gps; }, "the reconstructed volume");
  if (ref_ && volume_.bytes != ref_->reconstructor().output().bytes)
    throw InvariantError("the distributed reconstruction differs from the serial pipeline's");
  return volume_;
}

void DistributedPipeline::onVolume(const Message& m) {
  const VolumeMsg& vm = m.as<VolumeMsg>();
  const auto type = static_cast<ScalarType>(vm.scalarType);
  if (volume_.bytes.empty()) volume_.allocate(j_.grid, type);
  if (volume_.type != type) throw CommError("graphics processors sent volume pieces of different voxel types");
  const auto bpv = static_cast<std::size_t>(scalarBytes(type));
  const auto payload = m.payload<VolumeMsg>();
  const auto malformed = [&] { return CommError(fmt::format("a malformed volume piece from rank {}", m.source)); };
  if (payload.size() / sizeof(VolumeBox) < vm.boxes) throw malformed();
  std::size_t off = vm.boxes * sizeof(VolumeBox);
  for (std::uint32_t i = 0; i < vm.boxes; ++i) {
    VolumeBox vb;
    std::memcpy(&vb, payload.data() + i * sizeof(VolumeBox), sizeof vb);
    const Index3 lo(vb.lo[0], vb.lo[1], vb.lo[2]), hi(vb.hi[0], vb.hi[1], vb.hi[2]);
    const gp::Box3 box{lo, hi};
    if (box.empty() || glm::any(glm::lessThan(lo, Index3(0))) || glm::any(glm::greaterThan(hi, j_.grid.dims)) ||
        payload.size() - off < box.voxelCount() * bpv)
      throw malformed();
    const std::size_t rowBytes = static_cast<std::size_t>(hi.x - lo.x) * bpv;
    for (std::int64_t k = lo.z; k < hi.z; ++k)
      for (std::int64_t jj = lo.y; jj < hi.y; ++jj, off += rowBytes)
        std::memcpy(volume_.bytes.data() + j_.grid.linear(lo.x, jj, k) * bpv, payload.data() + off, rowBytes);
    volumeChange_.boxes.push_back(box);
  }
  if (off != payload.size()) throw malformed();
  if (vm.last) ++volumesDone_;
  if (volumeOutstanding_ && volumesDone_ == L_.gps) {
    volumeOutstanding_ = false;
    if (events_.volume) events_.volume(volume_, volumeChange_);
  }
}

}  // namespace pp5::host
