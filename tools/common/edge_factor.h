#pragma once
// A dataset edge as the wire's factor_t, for everything that plays files to a server
// (loopd-feed, the server benchmarks).
#include "loopd/factor_t.hpp"
#include "solvers/io/dataset.h"

namespace loopd::tools {

/// id = the edge index; keys are robot `robotFrom`'s pose e.from and, for a between edge,
/// robot `robotTo`'s pose e.to (odometry when `odometry`, else a loop closure), for a sighting
/// robot `robotFrom`'s landmark e.to.
loopd::factor_t edgeFactor(const io::Edge& e, int robotFrom, int robotTo, bool odometry);

}  // namespace loopd::tools
