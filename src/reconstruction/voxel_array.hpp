#pragma once
// Per-voxel state arrays for the reconstructors: zero-filled, on transparent
// huge pages where the system allows.
#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <new>
#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace pp5::gp {

// Asks for transparent huge pages on the whole pages inside [p, p + bytes)
// (before they are first touched, for it to take effect at once).
inline void adviseHugePages([[maybe_unused]] void* p, [[maybe_unused]] std::size_t bytes) {
#if defined(MADV_HUGEPAGE)
  constexpr std::uintptr_t kPage = 4096;
  const auto a = (reinterpret_cast<std::uintptr_t>(p) + kPage - 1) & ~(kPage - 1);
  const auto b = (reinterpret_cast<std::uintptr_t>(p) + bytes) & ~(kPage - 1);
  if (b > a) ::madvise(reinterpret_cast<void*>(a), b - a, MADV_HUGEPAGE);  // a hint: failing is harmless
#endif
}

// A zero-filled array for the per-voxel state. Grids are large and a slice
// visits its voxels a grid row apart, so with 4 KiB pages nearly every row
// costs a TLB miss; where the system allows, ask for transparent huge pages
// before the first touch.
template <typename T>
class VoxelArray {
public:
  VoxelArray() = default;
  explicit VoxelArray(std::size_t n) : n_(n) {
    constexpr std::size_t kHuge = std::size_t{2} << 20;
    const std::size_t bytes = std::max<std::size_t>(1, n * sizeof(T));
    const std::size_t rounded = (bytes + kHuge - 1) / kHuge * kHuge;
    void* p = std::aligned_alloc(kHuge, rounded);
    if (!p) throw std::bad_alloc();
    adviseHugePages(p, rounded);
    data_.reset(static_cast<T*>(p));
    std::fill_n(data_.get(), n_, T{});
  }
  std::size_t size() const { return n_; }
  T* data() { return data_.get(); }
  const T* data() const { return data_.get(); }
  T& operator[](std::size_t i) { return data_.get()[i]; }
  const T& operator[](std::size_t i) const { return data_.get()[i]; }

private:
  struct Free {
    void operator()(T* p) const { std::free(p); }
  };
  std::unique_ptr<T[], Free> data_;
  std::size_t n_ = 0;
};

inline void storeF32(std::uint8_t* bytes, std::size_t i, float v) { std::memcpy(bytes + 4 * i, &v, sizeof v); }

}  // namespace pp5::gp
