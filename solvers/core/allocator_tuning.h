#pragma once
// Process-wide malloc settings for long solves (loopd-solve, the server).

namespace loopd {

/// Keeps freed memory in the heap for reuse instead of returning it to the system at once.
/// iSAM2 frees and re-creates its top cliques every update (megabytes once loop closures
/// make the top dense). With glibc's defaults that memory went back to the system and came
/// back as fresh pages at every update: `loopd-solve --solver isam2 --incremental` on
/// sphere2500 + 1000 random closures took 282 s, 86 s of it in the kernel; with this, 238 s
/// and 38 s. Blocks up to keepBytes come from the heap, and up to keepBytes of free memory
/// stay at its top; the process keeps what a peak took (a graph that needed it once will
/// again).
void keepFreedMemoryForReuse(long keepBytes = 1L << 30);

}  // namespace loopd
