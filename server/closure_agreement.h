#pragma once
// Which of a robot pair's inter-robot loop closures agree on where one robot's frame lies in
// the other's, before anything joins the two frames. Each closure alone fixes that transform
// (M = x_r·Z·x_s⁻¹), so the first one to arrive, right or wrong, would decide it, and a wrong
// one bends both maps from then on in a way a robust solver only sees once true closures
// arrive and disagree with it (mm then rejected the true ones). Two closures agree when the
// cycle through them and the two robots' maps closes within the closures' own noise: the
// pairwise consistency test of PCM (robust/pairwise_consistency.h) on the two robots' odometry
// chains, each in its own frame, with the maps taken as exact between the closures' ends (the
// odometry's drift not added). Wrong closures agree with the true ones only by chance; a group
// of mutually consistent wrong ones agrees with itself, which no such test can tell.
#include <cstddef>
#include <vector>

#include "solvers/core/values.h"
#include "solvers/factors/factor.h"

namespace loopd::server {

/// Indices into `closures` (pose–pose between factors from one robot of the pair to the
/// other, in either direction, on single-frame keys) of the largest mutually consistent set
/// found, at `poses` (both robots' poses, each in its own frame); `odometry` (their odometry
/// factors) says which poses lie on one unbroken chain: closures across a break are not
/// judged. A closure from the higher robot to the lower is judged (by PCM) as its inverse, with the
/// same information (the test is isotropic in each block, see PCM's header).
std::vector<size_t> agreeingClosures(const std::vector<FactorPtr>& closures,
                                     const std::vector<FactorPtr>& odometry, const Values& poses,
                                     double probability);

}  // namespace loopd::server
