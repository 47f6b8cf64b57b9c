#pragma once
// UpdateResult::moved for a backend that re-solves the whole estimate: what changed.
#include <vector>

#include "solvers/core/values.h"

namespace loopd {

/// Variables of after that are new, or moved beyond threshold in some stored coordinate,
/// since before.
std::vector<Key> movedKeys(const Values& before, const Values& after, double threshold);

}  // namespace loopd
