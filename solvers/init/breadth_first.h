#pragma once
// The slots reachable from an anchor, in breadth-first order: what the linear initialisations
// number as unknowns (the anchor known, anything unreached left at its guess).
#include <functional>
#include <vector>

#include "solvers/core/values.h"
#include "solvers/graph/factor_graph.h"

namespace loopd {

/// adjacency[s]: the slots one factor joins to s. The anchor comes first.
std::vector<int> breadthFirstOrder(const std::vector<std::vector<int>>& adjacency, int anchor);

/// The unknowns of a linear start: per slot its first unknown (−1: the anchor, or not reached
/// and so known at its guess), and how many there are.
struct ReachableUnknowns {
  std::vector<int> index;
  int count = 0;
};

/// Numbers the slots reachable from the anchor through the two-key factors `joins` accepts
/// (ends not in `values` skipped), in breadth-first order, `dims(slot)` unknowns each.
ReachableUnknowns numberReachable(const FactorGraph& graph, const Values& values, int anchorSlot,
                                  const std::function<bool(const Factor&)>& joins,
                                  const std::function<int(int)>& dims);

}  // namespace loopd
