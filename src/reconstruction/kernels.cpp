#include "reconstruction/kernels.hpp"

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5::gp {

namespace {
// The registration: one line a method.
const Kernel* const kAll[] = {&kTentKernel, &kNearestKernel, &kTrilinearKernel};
}  // namespace

std::span<const Kernel* const> kernels() { return kAll; }

const Kernel& kernelFor(Method m) {
  for (const Kernel* k : kAll)
    if (k->method == m) return *k;
  throw InvariantError(fmt::format("no reconstruction method is registered for recon.method {}", static_cast<int>(m)));
}

}  // namespace pp5::gp
