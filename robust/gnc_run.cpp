#include "robust/gnc_run.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "robust/robust_factors.h"
#include "solvers/init/initialization.h"

namespace loopd {

GncBackend::Run::Run(GncBackend& backend, Values odometryStart, bool batchStartCandidate)
    : b_(backend),
      gnc_(backend.gnc_),
      graph_(backend.graph_),
      estimate_(backend.estimate_),
      weights_(backend.weights_),
      n_(backend.graph_.size()),
      start_(backend.estimate_),
      odometryStart_(std::move(odometryStart)),
      tls_(backend.gnc_.loss == GncLoss::TruncatedLeastSquares),
      noiseAware_(backend.gnc_.tailExponent >= 0.0 && backend.options_.robustParameter <= 0.0),
      odometryCandidate_(odometryStart_.size() == backend.estimate_.size() &&
                         odometryStart_.size() > 0),
      batchStartCandidate_(batchStartCandidate),
      refineCap_(backend.gnc_.refineIterations),
      decides_(tls_ || backend.gnc_.gmDecidesAtThreshold),
      acceptAt_(tls_ || !decides_ ? 0.5 : 0.25),
      fullIterations_(backend.optimizer().options().maxIterations),
      defaultLambda_(backend.optimizer().options().initialLambda),
      r2_(n_, 0.0),
      c2_(n_, 0.0),
      half_(n_, 0.0) {
  for (int i = 0; i < n_; ++i) {
    half_[i] = chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5);
    if (isUncertain(graph_[i]->role())) c2_[i] = b_.barc2(*graph_[i]), anyUncertain_ = true;
  }
  jointMarginal_ = [this, checkpoint =
                              b_.interruptCheckpoint()](const std::vector<std::vector<Key>>& sets) {
    return b_.jointMarginals(sets, checkpoint);
  };
  b_.outer_ = 0;
  b_.scale_ = 0.0;
  b_.refine_ = 0;
}

void GncBackend::Run::execute() {
  gncPass(true);
  if (!anyUncertain_) return;
  const std::string firstReason = reason_;
  cbar_ = c2_;
  gate_ = c2_;
  gated_ = noiseAware_ && estimateGate(gate_);  // refine, redo with the gate
  if (gated_ || odometryCandidate_) judgeCandidates();
  if (odometryCandidate_ && gnc_.consistentStart && rejectedCount() > 0) tryConsistentStart();
  // The kept solution, solved to convergence (its solves were capped); with the gate acting,
  // its decisions re-made at the converged estimate.
  solveToConvergence();
  runChecks(0);
  regateAtEnd();
  admitTogetherAtTail();
  if (batchStartCandidate_ && rejectedCount() == 0) tryBatchStart();
  reason_ = firstReason + log_;
  report();
}

void GncBackend::Run::residuals() {
  for (int i = 0; i < n_; ++i)
    if (c2_[i] > 0.0) r2_[i] = graph_[i]->chi2(estimate_);
}

// Solves with at most `cap` LM iterations (0: the optimizer's own limit), which the
// intermediate solves need only to track the weights; the kept solution is polished.
// With warmDamping, each solve starts from the damping the previous one ended with.
void GncBackend::Run::solveCapped(int cap, Solve kind) {
  OptimizerOptions& o = b_.optimizer().options();
  o.maxIterations = cap > 0 ? std::min(cap, fullIterations_) : fullIterations_;
  if (gnc_.warmDamping && warmLambda_ > 0.0) o.initialLambda = warmLambda_;
  auto reset = [&] {
    b_.optimizer().options().maxIterations = fullIterations_;
    b_.optimizer().options().initialLambda = defaultLambda_;
  };
  try {
    if (kind == Solve::LeastSquares)
      b_.BatchBackend::optimize();
    else
      last_ = b_.solveOnce();
  } catch (...) {
    reset();
    throw;
  }
  reset();
  warmLambda_ = b_.lastSolve_.finalTrustParameter;
}

void GncBackend::Run::solveWeighted(int cap) {
  solveCapped(cap, Solve::Weighted);
  iterations_ += last_.iterations;
  residuals();
}

// One GNC with thresholds c2: from start_ (first: the current estimate) the plain
// least-squares solve, then the μ steps; or (fromOdometry) the μ steps straight from the
// odometry start, μ₀ set by the residuals there.
void GncBackend::Run::gncPass(bool first, bool fromOdometry, const Values* from) {
  double& mu = b_.mu_;
  int& outer = b_.outer_;
  weights_.assign(n_, 1.0);
  if (fromOdometry) {
    estimate_.assignFrom(odometryStart_);
  } else {
    if (from)
      estimate_.assignFrom(*from);
    else if (!first)
      estimate_.assignFrom(start_);
    // Plain least squares (all weights 1); capped when the GNC follows (it only starts it).
    solveCapped(anyUncertain_ ? gnc_.stepIterations : 0, Solve::LeastSquares);
    iterations_ += b_.summary_.iterations;
    if (first) initialChi2_ = b_.summary_.initialChi2;
    last_.finalChi2 = b_.summary_.finalChi2;
    last_.converged = b_.summary_.converged;
  }
  outer = 0;
  if (!anyUncertain_) return;
  residuals();
  double maxRatio = 0.0;
  for (int i = 0; i < n_; ++i)
    if (c2_[i] > 0.0) maxRatio = std::max(maxRatio, r2_[i] / c2_[i]);
  reason_ = "max outer iterations";
  if (!tls_) {
    mu = std::max(1.0, 2.0 * maxRatio);
  } else {
    if (maxRatio <= 1.0) {
      mu = 0.0;
      reason_ = "gnc: every residual below the inlier threshold";
      solveWeighted(0);  // every closure in: the plain least squares, to convergence
      return;
    }
    mu = std::max(1e-6, 1.0 / (2.0 * maxRatio - 1.0));
  }
  double prevCost = -1.0;
  for (outer = 1; outer <= gnc_.maxOuterIterations; ++outer) {
    b_.updateWeights(r2_, c2_);
    if (!gnc_.warmStart) estimate_.assignFrom(start_);
    solveWeighted(gnc_.stepIterations);
    const double cost = last_.finalWeightedCost;
    if (!tls_ && mu <= 1.0) {
      reason_ = "gnc: mu reached 1";
      break;
    }
    if (tls_) {
      bool binary = true;
      for (int i = 0; i < n_ && binary; ++i)
        binary = weights_[i] < gnc_.weightsTol || weights_[i] > 1.0 - gnc_.weightsTol;
      if (binary) {
        reason_ = "gnc: weights converged";
        break;
      }
    }
    if (prevCost >= 0.0 &&
        std::abs(cost - prevCost) <= gnc_.relativeCostTol * std::max(prevCost, 1e-12)) {
      reason_ = "gnc: cost converged";
      break;
    }
    prevCost = cost;
    mu = tls_ ? mu * gnc_.muStep : std::max(1.0, mu / gnc_.muStep);
  }
  outer = std::min(outer, gnc_.maxOuterIterations);
  // Report the weights at the final estimate (the last solve moved it); the solve itself
  // used the previous ones, as in GTSAM.
  b_.updateWeights(r2_, c2_);
}

// A kept answer's capped solves, finished: refined against the gate if it acts.
void GncBackend::Run::solveToConvergence() {
  if (gated_ || (decides_ && !tls_))
    refine(0);
  else
    solveWeighted(0);
}

// Decides 0/1 against the gate at the current estimate, re-solves (at most `cap` iterations
// each), repeats.
void GncBackend::Run::refine(int cap) {
  for (int it = 0; it < gnc_.maxRefineIterations; ++it) {
    bool changed = false;
    for (int i = 0; i < n_; ++i) {
      if (c2_[i] <= 0.0) continue;
      const double w = r2_[i] <= gate_[i] ? 1.0 : 0.0;
      changed = changed || w != weights_[i];
      weights_[i] = w;
    }
    if (!changed && it > 0) break;
    ++b_.refine_;
    solveWeighted(cap);
    if (!changed) break;
  }
}

// The truncated cost every candidate minimizes: trusted χ² + Σ min(χ², gate).
double GncBackend::Run::tlsCost() const { return tlsCost(gate_); }

double GncBackend::Run::tlsCost(const std::vector<double>& caps) const {
  double cost = 0.0;
  for (int i = 0; i < n_; ++i)
    cost += c2_[i] > 0.0 ? std::min(r2_[i], caps[i]) : graph_[i]->chi2(estimate_);
  return cost;
}

GncBackend::Run::Candidate GncBackend::Run::snapshot() const {
  return Candidate{tlsCost(), estimate_, weights_, r2_, last_};
}

void GncBackend::Run::restore(const Candidate& c) {
  estimate_.assignFrom(c.estimate);
  weights_ = c.weights;
  r2_ = c.r2;
  last_ = c.last;
}

int GncBackend::Run::rejectedCount() const {
  int count = 0;
  for (int i = 0; i < n_; ++i) count += cbar_[i] > 0.0 && !accepted(i);
  return count;
}

// Every uncertain factor's threshold below its χ²_dim(p) default.
bool GncBackend::Run::belowDefaults(const std::vector<double>& thresholds) const {
  for (int i = 0; i < n_; ++i)
    if (cbar_[i] > 0.0 && !(thresholds[i] < cbar_[i])) return false;
  return true;
}

void GncBackend::Run::consider(const std::string& name) {
  Candidate c = snapshot();
  char buf[64];
  std::snprintf(buf, sizeof buf, "%s%s %.6g", costs_.empty() ? "" : ", ", name.c_str(), c.cost);
  costs_ += buf;
  if (bestName_.empty() || c.cost < best_.cost) {
    best_ = std::move(c);
    bestName_ = name;
  }
}

// Candidates, the one with the lowest truncated cost kept. A: the first GNC (refined against
// the gate). B (gate acting, rerunWithGate): the GNC redone from the same start with c̄² =
// gate — heavy-tailed closures (over-confident information) may have been dropped by the
// χ²_dim(p) threshold in the non-convex phase. C: the GNC from the odometry start (no
// least-squares solve with every closure: outliers cannot bend the start), with the same
// thresholds.
void GncBackend::Run::judgeCandidates() {
  if (gated_) refine(refineCap_);
  consider("first");
  const int firstOuter = b_.outer_;
  c2_ = gate_;
  if (gated_ && (gnc_.rerunWithGate || !odometryCandidate_)) {
    gncPass(false);
    b_.outer_ += firstOuter;
    refine(refineCap_);
    consider("redone with the gate");
  }
  auto fromOdometry = [&] {
    const int before = b_.outer_;
    gncPass(false, true);
    b_.outer_ += before;
    if (gated_) refine(refineCap_);
    consider("from odometry");
  };
  if (odometryCandidate_) fromOdometry();
  restore(best_);
  log_ += "; kept " + bestName_ + " (truncated costs " + costs_ + ")";
  // The gate was estimated from the first GNC, whose solution outliers may have bent: its
  // accepted closures' tail is then too wide. Re-estimate it from the kept solution; while
  // it shrinks by more than widenFactor, refine the kept solution against it and redo the
  // GNC from the odometry start with it, keep the cheaper (under the new gate).
  int rounds = 0;
  const double firstGate = b_.tailGate_;
  for (int round = 0; gated_ && round < gnc_.maxGateRounds; ++round) {
    if (!shrinkGate()) break;
    bestName_.clear();
    costs_.clear();
    refine(refineCap_);
    consider("kept, refined");
    if (odometryCandidate_) fromOdometry();
    restore(best_);
    char buf[96];
    std::snprintf(buf, sizeof buf, "; gate re-estimated: %.3g x chi2_dim(0.5), kept ",
                  b_.tailGate_);
    log_ += buf + bestName_ + " (" + costs_ + ")";
    ++rounds;
  }
  const bool tightened = gated_ && belowDefaults(gate_);
  if ((rounds > 0 || tightened) && gnc_.readmit)
    readmitAtTail(rounds > 0 ? firstGate : std::numeric_limits<double>::infinity());
}

// Nothing rejected: the answer is a least-squares solution in the basin of the trusted
// start, which odometry alone can put far off (MIT: 770.66). The batch solvers' start, built
// with every closure (none of them an outlier by this answer), is then the better start for
// that least squares. Its GNC, solved to convergence, replaces the answer only if it rejects
// nothing either and is cheaper at the gate: one that rejects closures of clean data can be
// cheaper at the gate too (kitti_00 under gnc-gm: a long loop whose removal gains more than
// its threshold), and this check is not there to change decisions.
void GncBackend::Run::tryBatchStart() {
  const Values batchStart = initializeLinearFromLowestPose(graph_, start_);
  if (batchStart.size() != estimate_.size()) return;
  const Candidate kept = snapshot();
  const int outer = b_.outer_;
  gncPass(false, false, &batchStart);
  b_.outer_ += outer;
  solveToConvergence();
  const Candidate tried = snapshot();
  const int rejected = rejectedCount();
  const bool better = rejected == 0 && tried.cost < kept.cost;
  if (!better) restore(kept);
  char buf[200];
  std::snprintf(buf, sizeof buf,
                "; nothing rejected, GNC from the batch solvers' start: %s (truncated cost "
                "%.6g -> %.6g, %d rejected)",
                better ? "kept" : "not kept", kept.cost, tried.cost, rejected);
  log_ += buf;
}

void GncBackend::Run::report() {
  if (noiseAware_) {
    char buf[160];
    std::snprintf(buf, sizeof buf,
                  "; noise scale %.3g, tail gate %.3g x chi2_dim(0.5)%s, %d refinement solves",
                  b_.scale_, b_.tailGate_, gated_ ? " (acting)" : "", b_.refine_);
    reason_ += buf;
  }
  SolveSummary& s = b_.summary_;
  s.iterations = iterations_;
  s.initialChi2 = initialChi2_;
  s.finalChi2 = last_.finalChi2;
  s.converged = last_.converged;
  s.budgetSpent = false;  // the schedule ended (or its outer budget did): a new one starts over
  s.stopReason = reason_;
}

}  // namespace loopd
