#include "solvers/core/allocator_tuning.h"

#include <cstdlib>  // defines __GLIBC__ on glibc
#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace loopd {

void keepFreedMemoryForReuse(long keepBytes) {
#if defined(__GLIBC__)
  // Setting either disables glibc's dynamic thresholds; both are set so that blocks up to
  // keepBytes come from the heap (not a fresh mmap each time) and stay there once freed.
  mallopt(M_MMAP_THRESHOLD, static_cast<int>(keepBytes));
  mallopt(M_TRIM_THRESHOLD, static_cast<int>(keepBytes));
#else
  (void)keepBytes;
#endif
}

}  // namespace loopd
