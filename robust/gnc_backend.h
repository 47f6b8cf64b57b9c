#pragma once
// Graduated non-convexity (Yang, Antonante, Tzoumas, Carlone, RA-L 2020) as a batch Backend:
// a BatchBackend whose factorWeights() carry the GNC weights of the uncertain factors
// (trusted factors always weigh 1). optimize(): the plain least-squares solve, then outer
// steps — update the weights in closed form at the current residuals, re-solve warm from the
// previous solution (solveOnce(), reusing the symbolic factorization), move μ — until the
// notes' stopping rule holds. Each factor's inlier threshold c̄² is χ²_dim(0.99) in our rᵀr
// convention (GTSAM's barcSq is half of that, in its ½-scaled error).
//
//   GM:  w = (μc̄²/(r² + μc̄²))²,  μ₀ = 2·max r²/c̄², μ ← max(1, μ/1.4), stop at μ = 1.
//   TLS: w = 1 | c̄/|r|·√(μ(μ+1)) − μ | 0,  μ₀ = 1/(2·max r²/c̄² − 1) (≥ 1e-6), μ ← 1.4μ,
//        stop when every weight is within 1e-4 of 0 or 1; return at once if all r² ≤ c̄².
//   Both: stop when the weighted cost changes by less than 1e-5 relatively, or after 100
//   outer steps. The kept answer ends decided 0/1 (GM: GncOptions::gmDecidesAtThreshold).
#include <exception>
#include <functional>
#include <vector>

#include "solvers/batch/batch_backend.h"

namespace loopd {

enum class GncLoss { GemanMcClure, TruncatedLeastSquares };

struct GncOptions {
  GncLoss loss = GncLoss::TruncatedLeastSquares;
  double inlierProbability = 0.99;  // c̄² = χ²_dim(p); BackendOptions::robustParameter > 0
                                    // overrides c̄² directly (the same for every dimension)
  double muStep = 1.4;
  double relativeCostTol = 1e-5;
  double weightsTol = 1e-4;
  int maxOuterIterations = 100;
  double rejectBelow = 0.5;
  /// Start from the trusted factors' linear initialization (outliers cannot bend it).
  bool trustedInitialization = true;
  /// Also run the GNC from the odometry start (the trusted factors' linear initialization,
  /// without the least-squares solve over every closure) and keep it if its truncated cost is
  /// lower (needs trustedInitialization). On every solve, also without a linear
  /// initialization of the values (the server's, `--init file`): the server's gnc-tls ran
  /// without it, and without the consistent-set start that follows it, and ended bent by
  /// grouped wrong closures (manhattan + 100 in groups, ATE 5.9 m).
  bool odometryStart = true;
  /// If the first solve's answer rejects nothing, it is a least-squares solution in the
  /// trusted start's basin: also run the GNC from the batch solvers' linear initialization
  /// (every factor) and keep it if it rejects nothing either and its truncated cost is lower
  /// (MIT: 770.66 → 41.163 under `gnc-gm`). Needs trustedInitialization and a linear
  /// initialization.
  bool batchStartWhenNoneRejected = true;
  /// Outer steps start from the previous solution (true) or, as GTSAM does, from the values
  /// the GNC started from (false).
  bool warmStart = true;
  /// Levenberg–Marquardt iterations per μ step and for the least-squares start (0: the
  /// optimizer's own limit). A μ step only has to track the moving weights: solving each to
  /// convergence crawled (parking-garage: 100 iterations a step, 3.5× the time, same answer).
  int stepIterations = 10;
  /// Iterations per solve while refining a candidate's 0/1 decisions (0: the optimizer's own);
  /// the kept candidate is then solved to convergence.
  int refineIterations = 20;
  /// Each solve starts from the Levenberg–Marquardt damping the previous one ended with, not
  /// the optimizer's near-Gauss–Newton default: on parking-garage half the iterations of a
  /// fresh start were rejected while the damping climbed back, eating the capped budgets.
  bool warmDamping = true;
  /// Also redo the GNC from the least-squares start with c̄² = the gate (candidate B below).
  /// Off: the odometry-start candidate, judged by the same gate, has always done as well.
  bool rerunWithGate = false;
  /// If closures are rejected, also start from the largest pairwise-consistent set of
  /// closures (robust/pairwise_consistency.h) and keep it if its truncated cost is lower
  /// (the candidate is decided 0/1; needs the odometry start).
  bool consistentStart = true;
  /// If the consistent-set candidate's own gate is tighter (by widenFactor, for every
  /// closure) than the kept solution's, judge both at it first: a kept solution bent by
  /// consistent groups has a wide gate estimated from its own bent tail, under which bending
  /// is cheap (parking-garage with 1000 wrong closures in groups of 10, seeds 3 and 4).
  bool judgeAtOwnGate = true;
  double consistencyProbability = 0.999;
  /// Noise-aware gate (off when BackendOptions::robustParameter > 0 or tailExponent < 0).
  /// Loop-closure information is rarely calibrated: intel's true closures sit at
  /// χ² ≈ 0.007·χ²_dim, manhattan's have a heavy tail (max 30× the median) that a
  /// χ²_dim(0.99) test cuts. After the GNC, the accepted closures' normalized χ²
  /// (q = χ²/χ²_dim(0.5)) give
  ///   g = min(medianFactor·q50, q99·(q99/q90)^tailExponent)
  /// (the tail extrapolated by its own steepness, capped by a multiple of the median). Only if
  /// g·χ²_dim(0.5) > widenFactor·c̄² for some factor (a heavy tail: manhattan) does it act:
  /// with gate = max(c̄², g·χ²_dim(0.5)), candidate A is this GNC refined (decide 0/1, χ² ≤
  /// gate, at the current estimate, re-solve, until no decision changes), candidate B (if
  /// rerunWithGate) the GNC redone from the same start with c̄² = gate, refined likewise, and
  /// the odometry-start GNC with c̄² = gate, refined likewise; the one with the lower
  /// truncated cost Σ_trusted χ² + Σ min(χ², gate) is kept. Otherwise the plain GNC stands.
  double tailExponent = 3.0;
  double medianFactor = 100.0;
  double widenFactor = 2.0;
  /// Also act when every gate is below c̄²/widenFactor (under-confident information), with
  /// gate = g·χ²_dim(0.5) itself.
  bool tighten = true;
  int maxRefineIterations = 20;
  /// Re-estimations of the gate from the kept solution (each while it shrinks by more than
  /// widenFactor: a gate from a bent first solution is too wide).
  int maxGateRounds = 3;
  /// After gate rounds: decide once more against the accepted closures' uncapped tail
  /// extrapolation (≤ the first gate), re-admitting rejected closures consistent with the
  /// settled solution.
  bool readmit = true;
  /// Finally, re-admit rejected closures (alone, and in clusters whose ends lie within
  /// admitWindow poses of each other's) whose predicted cost rise rᵀ(I + JΣJᵀ)⁻¹r (Σ: joint
  /// marginal of their variables) is below their gates, and reject clusters of accepted
  /// closures (ends within dropWindow) whose predicted removal gain rᵀ(I − JΣJᵀ)⁻¹r exceeds
  /// their gates (robust/closure_leverage.h), each kept if the truncated cost does drop; both
  /// in turn for up to checkRounds rounds, while either changes something. Clusters have at
  /// most maxCluster closures.
  bool recheckRejected = true;
  bool dropClusters = true;
  /// TLS (and GM with gmDecidesAtThreshold): a group is re-admitted only if its predicted cost rise
  /// is also within medianFactor × the noise scale × χ²_dim(0.5) per closure. Under the wide tail
  /// gate a flexible map lets one wrong closure bend it for less than its gate (parking-garage,
  /// 1000 random, seed 2: ATE 2.1 m, chi2 +3.9%); a true closure held out fits near the noise.
  bool admitWithinNoise = true;
  /// After the checks, re-estimate the gate from the final solution (up to maxGateRounds
  /// times, while it shrinks by more than widenFactor), decide again and re-run the checks.
  bool regateAtEnd = true;
  /// TLS (and GM with gmDecidesAtThreshold), the gate not acting but the tail gate wider than c̄²
  /// (torus3D): when every rejected closure misfits by less than medianFactor × the noise scale ×
  /// χ²_dim(0.5), re-admit them together, decide again against c̄², and keep that if its truncated
  /// cost capped at max(c̄², the tail gate) is lower — true closures that hold tension together cost
  /// less rejected at c̄² alone.
  bool admitTogetherAtTail = true;
  /// GM: a closure counts as accepted while its weight is at least 0.25, GM's weight at
  /// χ² = c̄² when μ = 1 (the TLS midpoint 0.5 is χ² = 0.41·c̄² there: the gate read from those
  /// cut the true closures' tail, and true closures past it went out: smallGrid3D, manhattan +
  /// 100 in groups, seed 3); the kept answer is decided 0/1 against the thresholds and solved
  /// again (soft weights left clean tinyGrid3D +0.98% off its optimum), and the checks that
  /// need 0/1 decisions run as for TLS: clusters re-admitted within the noise, the drop check,
  /// the gate re-estimated at the end, the re-admission at the tail gate (manhattan + 1000
  /// random, seed 1: ATE 13.4 m before, 2.3 cm). Off: accepted at 0.5, soft weights, and of
  /// the checks only single re-admissions.
  bool gmDecidesAtThreshold = true;
  int checkRounds = 4;
  int admitWindow = 50;
  int dropWindow = 10;
  int maxCluster = 20;
  /// Asked at every Levenberg–Marquardt iteration, at every closure's row of the
  /// consistent-set test and before every group's joint marginal in the checks; true makes
  /// optimize() throw GncInterrupted (RisamBackend's GNC look, which then leaves its answer as it
  /// was). Unset: never.
  std::function<bool()> interrupt;
};

/// Thrown out of GncBackend::update()/optimize() when GncOptions::interrupt returns true; the
/// backend's estimate and weights are then partway. Not a runtime_error or logic_error: the
/// handlers of failures inside (a singular marginal is "cannot be told") let it pass.
struct GncInterrupted : std::exception {
  const char* what() const noexcept override { return "gnc: interrupted"; }
};

/// Noise scale and tail gate of normalized χ² values q_i = χ²_i/χ²_{dim_i}(0.5): scale = the
/// median (1 for honest information, < 1 under-confident, > 1 over-confident), tail =
/// q99·(q99/q90)^exponent, gate = min(medianFactor·median, tail). All 0 with fewer than 10
/// values.
struct TailGate {
  double scale = 0.0, gate = 0.0, tail = 0.0;
};
TailGate tailGate(std::vector<double> q, double exponent, double medianFactor);

class GncBackend : public BatchBackend {
 public:
  GncBackend(BackendOptions options, GncOptions gnc);

  std::string name() const override;
  void optimize() override;
  std::vector<std::pair<FactorId, double>> decisions() const override;
  std::vector<FactorId> rejected() const override;
  bool judgesUncertain() const override { return true; }

  int outerIterations() const { return outer_; }
  double finalMu() const { return mu_; }
  /// The noise scale, the tail gate (0 if not run) and the refinement solves of the last run.
  double noiseScaleUsed() const { return scale_; }
  double tailGateUsed() const { return tailGate_; }
  int refineIterations() const { return refine_; }

 protected:
  const double* factorWeights() const override {
    return weights_.size() == static_cast<size_t>(graph_.size()) ? weights_.data() : nullptr;
  }

 private:
  class Run;  // one optimize() call (robust/gnc_run.h)

  double barc2(const Factor& f) const;
  /// Throws GncInterrupted if GncOptions::interrupt says so; empty without an interrupt.
  std::function<void()> interruptCheckpoint() const;
  /// The trusted factors' linear initialization from the lowest pose (the odometry start);
  /// empty without a pose or a trusted factor. alsoUse: per factor, uncertain ones to use too.
  Values trustedLinearStart(const std::vector<char>& alsoUse = {}) const;
  /// Whether some variable is touched by no trusted factor (only by uncertain ones).
  bool someVariableUntrusted() const;
  void updateWeights(const std::vector<double>& r2, const std::vector<double>& c2);

  GncOptions gnc_;
  std::vector<double> weights_;
  double mu_ = 0.0;
  int outer_ = 0;
  double scale_ = 0.0, tailGate_ = 0.0;
  int refine_ = 0;
};

}  // namespace loopd
