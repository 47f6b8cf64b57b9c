#include "tools/common/process_stats.h"

#include <sys/resource.h>

namespace loopd::tools {

double peakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
}

}  // namespace loopd::tools
