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
//
// The closures' stated noise is often far wider than their real noise (parking-garage's:
// σ 1 m and 0.5–1 rad, while its optimum leaves them millimetres off). Judged at the stated
// noise, any two closures agree over the lever arm of a robot's map, and two random wrong
// ones joined robots 1 and 2 of parking-garage in three robots (mm and dcs then rejected
// thousands of true closures). So the test is narrowed by how well the robots' own closures
// of one revisit agree with each other, as PCM calibrates itself on short cycles.
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
/// `closureScale` multiplies the closures' stated covariances (ownClosureNoiseScale).
std::vector<size_t> agreeingClosures(const std::vector<FactorPtr>& closures,
                                     const std::vector<FactorPtr>& odometry, const Values& poses,
                                     double probability, double closureScale = 1.0);

/// How much wider than the revisit pairs' calibration the test is taken: pairs of closures
/// farther apart also carry the maps' error between their ends, which the test leaves out
/// (sphere2500's first true closures between two robots agreed from 3×; 10× leaves room).
constexpr double kFartherPairsMargin = 10.0;

/// The factor by which the stated covariances of `ownClosures` (the two robots' own loop
/// closures, each within one robot, those the solver rejects left out; closures not solved
/// yet count too) are off: PCM's calibration (robust/pairwise_consistency.h) on the pairs of
/// them from one revisit, with the maps taken as exact as the agreement test takes them (the
/// median of those pairs' statistic against χ²_dim(0.5)), times kFartherPairsMargin, at most
/// 1: the test is only narrowed. 1 when there are too few such pairs.
double ownClosureNoiseScale(const std::vector<FactorPtr>& ownClosures,
                            const std::vector<FactorPtr>& odometry, const Values& poses);

}  // namespace loopd::server
