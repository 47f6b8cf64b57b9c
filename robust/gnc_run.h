#pragma once
// One GncBackend::optimize() call: the GNC passes, the noise-aware gate, the candidates
// judged by the truncated cost, and the re-checks of single decisions. The state the steps
// share (residuals, thresholds, the gate, the log) lives here for the length of the call;
// what outlives it (weights, μ, the gate and scale reported) stays in the backend.
//   gnc_run.cpp     the passes, solving, 0/1 refinement, candidates, the report
//   gnc_gate.cpp    the noise-aware gate: estimate, shrink, re-admit at the tail
//   gnc_checks.cpp  admit-fitting / drop-bending checks and the consistent-set start
#include <string>
#include <vector>

#include "robust/closure_leverage.h"
#include "robust/gnc_backend.h"

namespace loopd {

class GncBackend::Run {
 public:
  /// odometryStart: the trusted factors' linear initialization (empty if none);
  /// batchStartCandidate: the first pass starts from it, and the batch solvers' start is a
  /// candidate if nothing is rejected (GncOptions::batchStartWhenNoneRejected).
  Run(GncBackend& backend, Values odometryStart, bool batchStartCandidate);
  void execute();

 private:
  // A solution with its truncated cost at the gate when taken.
  struct Candidate {
    double cost;
    Values estimate;
    std::vector<double> weights, r2;
    OptimizerResult last;
  };
  enum class Solve { LeastSquares, Weighted };

  // Solving (gnc_run.cpp).
  void residuals();
  void solveCapped(int cap, Solve kind);
  void solveWeighted(int cap);
  /// from: the start of the least-squares solve (default: start_, or the current estimate
  /// for the first pass).
  void gncPass(bool first, bool fromOdometry = false, const Values* from = nullptr);
  void refine(int cap);
  void solveToConvergence();
  double tlsCost() const;  // at gate_
  double tlsCost(const std::vector<double>& caps) const;
  Candidate snapshot() const;
  void restore(const Candidate& c);
  /// Whether the current weights take factor i in (weight ≥ acceptAt_).
  bool accepted(int i) const { return weights_[i] >= acceptAt_; }
  int rejectedCount() const;
  bool belowDefaults(const std::vector<double>& thresholds) const;
  void consider(const std::string& name);
  void judgeCandidates();
  void tryBatchStart();
  void report();

  // The gate (gnc_gate.cpp).
  std::vector<double> acceptedNormalized() const;
  /// medianFactor × the current noise scale, in factor i's χ² units (the gate's median cap).
  double medianCap(int i) const;
  bool estimateGate(std::vector<double>& out);
  bool shrinkGate();
  void readmitAtTail(double cap);
  void admitTogetherAtTail();
  void regateAtEnd();

  // Checks of single decisions and the consistent-set start (gnc_checks.cpp).
  bool tryDecisions(const std::vector<int>& factors, double weight, const char* what, int cap,
                    const std::vector<double>* judgeCaps = nullptr);
  std::vector<int> uncertainWhere(bool accepted) const;
  std::vector<double> predictedNet(const std::vector<std::vector<int>>& groups, GroupChange change);
  bool admitFitting(int cap);
  bool dropBending(int cap);
  void runChecks(int cap);
  void tryConsistentStart();

  GncBackend& b_;
  const GncOptions& gnc_;
  const FactorGraph& graph_;
  Values& estimate_;
  std::vector<double>& weights_;
  const int n_;
  const Values start_;  // the estimate the first pass started from
  const Values odometryStart_;
  const bool tls_, noiseAware_, odometryCandidate_, batchStartCandidate_;
  const int refineCap_;
  const bool decides_;     // 0/1 decisions at the end: TLS, or GM with gmDecidesAtThreshold
  const double acceptAt_;  // 0.5; GM with GncOptions::gmDecidesAtThreshold: 0.25
  // The optimizer's own limits, restored after each capped solve.
  const int fullIterations_;
  const double defaultLambda_;
  double warmLambda_ = 0.0;  // 0: the optimizer's own initial damping

  std::vector<double> r2_, c2_;  // χ² at the estimate and the thresholds in use
  std::vector<double> half_;     // χ²_dim(0.5) per factor: the normalization of χ²
  std::vector<double> cbar_;     // the χ²_dim(p) thresholds
  std::vector<double> gate_;     // the thresholds the candidates are judged by
  bool anyUncertain_ = false, gated_ = false;
  int iterations_ = 0;
  double initialChi2_ = 0.0;
  OptimizerResult last_;
  std::string reason_, log_;  // the pass's stop reason; what the candidates did
  Candidate best_;
  std::string bestName_, costs_;
  JointMarginalsFn jointMarginal_;
};

}  // namespace loopd
