#pragma once
// A fixed-capacity array of zeros that costs memory only where it is written.
//
// The ray cache holds every lattice sample of its rays, yet a view of an
// ultrasound volume writes only the few percent of them that are not
// transparent. Storage comes zeroed from the operating system (an anonymous
// mapping for large arrays, calloc for small ones), so a page takes memory
// and time only once a sample is written to it: a new cache neither clears
// nor faults in hundreds of MiB it will never touch.
//
// The array never clears itself: the owner must write zeros back over what it
// wrote before calling resize() (RayCache keeps a flag per page it wrote).
// Growing past the capacity maps new zeroed storage, with half again as much
// room, so that the next views, which differ in size by a few tens of percent,
// fit; the room beyond the size is address space only.
#include <sys/mman.h>

#include <cstddef>
#include <cstdlib>
#include <new>
#include <type_traits>
#include <utility>

namespace pp5::pp {

template <class T>
class ZeroedArray {
  static_assert(std::is_trivially_copyable_v<T> && std::is_arithmetic_v<T>, "zero bits must be the value 0");

public:
  ZeroedArray() = default;
  ZeroedArray(const ZeroedArray&) = delete;
  ZeroedArray& operator=(const ZeroedArray&) = delete;
  ZeroedArray(ZeroedArray&& o) noexcept { swap(o); }
  ZeroedArray& operator=(ZeroedArray&& o) noexcept {
    if (this != &o) {
      release();
      swap(o);
    }
    return *this;
  }
  ~ZeroedArray() { release(); }

  T* data() { return p_; }
  const T* data() const { return p_; }
  std::size_t size() const { return size_; }
  std::size_t capacity() const { return cap_; }

  // n elements; all of them are zero if every element written since the
  // last resize() was set back to zero.
  void resize(std::size_t n) {
    if (n > cap_) {
      release();
      allocate(n + n / 2);
    }
    size_ = n;
  }

private:
  static constexpr std::size_t kMapBytes = std::size_t{1} << 20;  // mmap from 1 MiB, calloc below
  T* p_ = nullptr;
  std::size_t size_ = 0, cap_ = 0;
  bool mapped_ = false;

  void allocate(std::size_t n) {
    const std::size_t bytes = n * sizeof(T);
    if (bytes >= kMapBytes) {
      void* m = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
      if (m == MAP_FAILED) throw std::bad_alloc();
      p_ = static_cast<T*>(m);
      mapped_ = true;
    } else {
      p_ = static_cast<T*>(std::calloc(n ? n : 1, sizeof(T)));
      if (!p_) throw std::bad_alloc();
      mapped_ = false;
    }
    cap_ = n;
  }
  void release() {
    if (p_) {
      if (mapped_) ::munmap(p_, cap_ * sizeof(T));
      else std::free(p_);
    }
    p_ = nullptr;
    size_ = cap_ = 0;
    mapped_ = false;
  }
  void swap(ZeroedArray& o) noexcept {
    std::swap(p_, o.p_);
    std::swap(size_, o.size_);
    std::swap(cap_, o.cap_);
    std::swap(mapped_, o.mapped_);
  }
};

}  // namespace pp5::pp
