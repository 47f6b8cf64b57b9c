#pragma once
// The slots reachable from an anchor, in breadth-first order: what the linear initialisations
// number as unknowns (the anchor known, anything unreached left at its guess).
#include <vector>

namespace loopd {

/// adjacency[s]: the slots one factor joins to s. The anchor comes first.
std::vector<int> breadthFirstOrder(const std::vector<std::vector<int>>& adjacency, int anchor);

}  // namespace loopd
