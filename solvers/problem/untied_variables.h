#pragma once
// Variables that nothing places: no chain of factors ties them to the gauge pose, and no prior
// to the world. Their part of the graph can sit anywhere at the same cost (the solvers' damping
// keeps it near its start), and its marginals do not exist.
#include <vector>

#include "solvers/core/key.h"
#include "solvers/core/values.h"
#include "solvers/graph/factor_graph.h"

namespace loopd {

/// The keys of `values` in parts of `graph` that hold neither `gauge` nor a one-key factor, in
/// slot order.
std::vector<Key> untiedVariables(const FactorGraph& graph, const Values& values, Key gauge);

}  // namespace loopd
