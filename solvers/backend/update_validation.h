#pragma once
// The checks every Backend applies to an update before touching its state, so an invalid
// update is rejected whole and leaves the backend as it was.
#include <unordered_map>

#include "solvers/backend/backend.h"

namespace loopd {

/// Throws std::invalid_argument if `u` carries ambiguous measurements (see flattenAmbiguous),
/// removes an unknown id or one id twice, gives an initial
/// value for a variable the backend already has, adds a duplicate id (an id may be removed and
/// re-added in the same update), or refers to a variable that is neither in `existing` nor in
/// `initial` (or has the wrong type there). `factorIndex` holds the backend's factor ids;
/// `initial` is u.initial, possibly completed by the backend (e.g. composed odometry).
void validateUpdate(const BackendUpdate& u, const Values& existing,
                    const std::unordered_map<FactorId, int>& factorIndex, const Values& initial);

}  // namespace loopd
