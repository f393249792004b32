#include "reconstruction/stored_volume.hpp"

#include "core/error.hpp"

namespace pp5::gp {

namespace {

class StoredVolume final : public Reconstructor {
public:
  explicit StoredVolume(const Volume& v) : Reconstructor(v.grid, ReconSettings{}), v_(v.as(ScalarType::F32)) {}
  InsertResult insert(const Frame&, const Mat4&, double) override { refuse(); }
  InsertResult advance(int, int, const Mat4&, double) override { refuse(); }
  void restorePrevious(const Frame&) override { refuse(); }
  const Volume& output() const override { return v_; }
  Volume weights() const override {
    Volume w;
    w.allocate(v_.grid, ScalarType::F32);
    for (std::size_t i = 0; i < v_.grid.voxelCount(); ++i) w.setValue(i, 1.0);
    return w;
  }
  bool covered(std::size_t) const override { return true; }

private:
  Volume v_;
  [[noreturn]] static void refuse() { throw InputError("a volume read from a file takes no frames"); }
};

}  // namespace

std::unique_ptr<Reconstructor> storedVolume(const Volume& v) { return std::make_unique<StoredVolume>(v); }

}  // namespace pp5::gp
