#pragma once
// Process figures for stats files.
namespace loopd::tools {

/// Peak resident set size of this process so far, in MiB.
double peakRssMb();

}  // namespace loopd::tools
