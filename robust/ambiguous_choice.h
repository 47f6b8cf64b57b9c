#pragma once
// Which alternative of each ambiguous measurement a Backend took, for every variant: mh says
// it (chosenAlternative); for the others, whose alternatives were flattened into ordinary
// factors, it is read off their per-factor decisions.
#include <vector>

#include "solvers/backend/backend.h"

namespace loopd {

/// Per measurement, in the given order: the position of the chosen alternative, or −1 for
/// none. Without hypotheses: the alternative not rejected with the highest decision weight
/// (ties: lowest χ² at the estimate); −1 when every alternative is rejected.
std::vector<int> chosenAlternatives(const Backend& backend,
                                    const std::vector<AmbiguousFactor>& measurements);

}  // namespace loopd
