#pragma once
// Initial values for variables that new factors introduce without one: composed from a
// variable already known through the factor (odometry: X_j = X_i·Z; a landmark from its
// first sighting), the way a robot's front-end would.
#include <vector>

#include "solvers/graph/factor_graph.h"

namespace loopd {

/// Adds to `guess` a value for every key of newFactors that is in neither `known` nor
/// `guess`, composing through factors whose other end is known (repeatedly, so a chain of
/// new poses is composed in order). Returns false if some key could not be reached.
bool predictMissingValues(const std::vector<FactorPtr>& newFactors, const Values& known,
                          Values& guess);

}  // namespace loopd
