#include "core/threads.hpp"

#include <algorithm>

#include <omp.h>

namespace pp5 {

int resolveThreads(int requested) { return requested > 0 ? requested : std::max(1, omp_get_max_threads()); }

}  // namespace pp5
