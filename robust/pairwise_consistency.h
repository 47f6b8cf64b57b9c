#pragma once
// Pairwise consistency of loop closures on the odometry chain (PCM, Mangelson et al.,
// ICRA 2018). Closures i = (a→b) and j = (c→d) are consistent when the cycle
// c →(odometry) a →(z_i) b →(odometry) d →(z_j⁻¹) c closes within its uncertainty:
//   Δ = z_j⁻¹·(x_c⁻¹x_a)·z_i·(x_b⁻¹x_d),   m = dim_t|Δ_t|²/V_t + dim_r|Δ_r|²/V_r < χ²_dim(p)
// with x the odometry poses and V_t, V_r the cycle's translation and rotation variances:
// the four links' own (isotropic: trace/dim of each link's covariance) plus, for
// translation, every rotation error's lever arm to d (σ_r²·|p_d − p_k|², prefix sums along
// the chain, so each pair costs O(1)). The set returned is the largest mutually consistent
// set a greedy clique search finds (seeded from the best-connected closures). Wrong
// closures agree with the odometry only by chance, true ones all agree with each other.
//
// Only pose–pose between closures are judged, and a pair only where each side's two ends lie
// on one unbroken odometry chain (ConsistencyOptions::unjudgedPairsAgree says what the other
// pairs count as); landmarks are left out. With several robots the poses are taken in the
// common frame and inter-robot closures through anchors (AnchoredBetweenFactor) as plain ones
// (solvers/init/common_frame.h); chains follow key order, robot by robot, joined where trusted
// between factors join them, and a closure between two chains is judged from the lower one.
#include <functional>
#include <vector>

#include "solvers/core/values.h"
#include "solvers/graph/factor_graph.h"

namespace loopd {

struct ConsistencyOptions {
  double probability = 0.999;  // the cycle test's χ²_dim quantile
  /// Covariance multipliers (the noise scale of odometry and of closures: the median
  /// normalized χ² at a solution; datasets' information is rarely calibrated).
  double odometryScale = 1.0;
  double closureScale = 1.0;
  int cliqueSeeds = 8;  // greedy clique searches, each from one of the best-connected closures
  /// Pairs the test cannot judge (their ends on other chains: two robots' own closures, or
  /// either side of a break in the odometry) count as consistent: the set is then the union of
  /// the largest sets of each pair of chains, as a start wants (the GNC's consistent start:
  /// with two robots it took one robot's closures alone). False: such pairs do not agree.
  bool unjudgedPairsAgree = false;
  /// Calibrate the covariances on short cycles: pairs whose two chains are each at most this
  /// many poses long (0: off); used when there are at least minCalibrationPairs of them.
  int calibrationWindow = 5;
  int minCalibrationPairs = 30;
  /// Stop once calibrated: only ConsistentSet::calibration, judged and calibrationPairs
  /// (O(closures·window) instead of the O(closures²) pair tests).
  bool calibrationOnly = false;
  /// Called before each closure's row of pair tests (the O(closures²) part); may throw to
  /// give the test up (GncOptions::interrupt).
  std::function<void()> checkpoint;
};

struct ConsistentSet {
  std::vector<char> member;  // per factor of the graph: 1 if in the consistent set
  int judged = 0;            // closures that took part
  int size = 0;              // closures in the set
  int calibrationPairs = 0;  // short cycles found
  double calibration = 1.0;  // the factor the covariances were found off by (1: not calibrated)
};

/// The largest mutually consistent set of the graph's loop closures at `odometry` (the
/// trusted factors' estimate: the odometry composed; each robot's in its own frame).
ConsistentSet pairwiseConsistentClosures(const FactorGraph& graph, const Values& odometry,
                                         const ConsistencyOptions& options = {});

}  // namespace loopd
