#include "robust/gnc_backend.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <unordered_map>

#include "robust/closure_leverage.h"
#include "robust/pairwise_consistency.h"
#include "robust/robust_factors.h"
#include "solvers/init/initialization.h"

namespace loopd {

TailGate tailGate(std::vector<double> q, double exponent, double medianFactor) {
  TailGate t;
  std::vector<double> v;
  for (double x : q)
    if (std::isfinite(x) && x >= 0.0) v.push_back(x);
  if (v.size() < 10) return t;
  std::sort(v.begin(), v.end());
  auto at = [&](double p) { return v[std::min(v.size() - 1, static_cast<size_t>(p * v.size()))]; };
  t.scale = at(0.5);
  const double p90 = at(0.9), p99 = at(0.99);
  if (!(p90 > 0.0)) return t;
  t.gate = std::min(medianFactor * t.scale, p99 * std::pow(p99 / p90, exponent));
  return t;
}

namespace {

double median(std::vector<double> v, double fallback) {
  if (v.empty()) return fallback;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

GncBackend::GncBackend(BackendOptions options, GncOptions gnc)
    : BatchBackend(std::move(options)), gnc_(gnc) {}

std::string GncBackend::name() const {
  return gnc_.loss == GncLoss::GemanMcClure ? "gnc-gm" : "gnc-tls";
}

double GncBackend::barc2(const Factor& f) const {
  if (options_.robustParameter > 0.0) return options_.robustParameter;
  return chi2Quantile(std::max(f.dim(), 1), gnc_.inlierProbability);
}

void GncBackend::updateWeights(const std::vector<double>& r2, const std::vector<double>& c2) {
  for (int i = 0; i < graph_.size(); ++i) {
    if (c2[i] <= 0.0) {
      weights_[i] = 1.0;
      continue;
    }
    const double r = r2[i], c = c2[i];
    if (gnc_.loss == GncLoss::GemanMcClure) {
      const double a = mu_ * c;
      weights_[i] = (a / (r + a)) * (a / (r + a));
    } else {
      const double lower = mu_ / (mu_ + 1.0) * c, upper = (mu_ + 1.0) / mu_ * c;
      if (r <= lower)
        weights_[i] = 1.0;
      else if (r >= upper)
        weights_[i] = 0.0;
      else
        weights_[i] = std::clamp(std::sqrt(c / r) * std::sqrt(mu_ * (mu_ + 1.0)) - mu_, 0.0, 1.0);
    }
  }
}

Values GncBackend::trustedLinearStart(const std::vector<char>& alsoUse) const {
  FactorGraph trusted;
  for (int i = 0; i < graph_.size(); ++i)
    if (!isUncertain(graph_[i]->role()) || (!alsoUse.empty() && alsoUse[i])) trusted.add(graph_[i]);
  Key anchor = 0;
  bool found = false;
  for (int s = 0; s < estimate_.size(); ++s)
    if (keyKind(estimate_.key(s)) == KeyKind::Pose && (!found || estimate_.key(s) < anchor))
      anchor = estimate_.key(s), found = true;
  if (!found || trusted.empty()) return Values();
  return initializeLinear(trusted, estimate_, anchor);
}

void GncBackend::optimize() {
  if (graph_.empty()) return;
  // The odometry start: the trusted factors' linear initialization (recomputed on every run;
  // empty if there is none), one of the GNC's starting points.
  Values odometryStart;
  const bool wantOdometryStart = gnc_.odometryStart && gnc_.trustedInitialization &&
                                 (firstSolve_ ? options_.linearInitialization : trustedInit_);
  if (wantOdometryStart) odometryStart = trustedLinearStart();
  if (firstSolve_ && options_.linearInitialization && gnc_.trustedInitialization) {
    trustedInit_ = true;
    // Linear initialization from the trusted factors only; the base class must not redo it
    // with the outliers included.
    const Values start = odometryStart.size() > 0 ? odometryStart : trustedLinearStart();
    if (start.size() > 0) estimate_ = start;
    options_.linearInitialization = false;
  }
  firstSolve_ = false;

  const int n = graph_.size();
  const Values start = estimate_;
  std::vector<double> r2(n, 0.0), c2(n, 0.0);
  auto residuals = [&] {
    for (int i = 0; i < n; ++i)
      if (c2[i] > 0.0) r2[i] = graph_[i]->chi2(estimate_);
  };
  bool anyUncertain = false;
  for (int i = 0; i < n; ++i)
    if (isUncertain(graph_[i]->role())) c2[i] = barc2(*graph_[i]), anyUncertain = true;
  outer_ = 0;
  scale_ = 0.0;
  refine_ = 0;
  int iterations = 0;
  double initialChi2 = 0.0;
  std::string reason;
  OptimizerResult last;
  const bool noiseAware = gnc_.tailExponent >= 0.0 && options_.robustParameter <= 0.0;
  // Solves with at most `cap` LM iterations (0: the optimizer's own limit), which the
  // intermediate solves need only to track the weights; the kept solution is polished.
  // With warmDamping, each solve starts from the damping the previous one ended with.
  const int fullIterations = optimizer().options().maxIterations;
  const double defaultLambda = optimizer().options().initialLambda;
  double warmLambda = 0.0;  // 0: the optimizer's own initial damping
  auto capped = [&](int cap, auto&& solve) {
    OptimizerOptions& o = optimizer().options();
    o.maxIterations = cap > 0 ? std::min(cap, fullIterations) : fullIterations;
    if (gnc_.warmDamping && warmLambda > 0.0) o.initialLambda = warmLambda;
    auto reset = [&] {
      optimizer().options().maxIterations = fullIterations;
      optimizer().options().initialLambda = defaultLambda;
    };
    try {
      solve();
    } catch (...) {
      reset();
      throw;
    }
    reset();
    warmLambda = lastSolve_.finalTrustParameter;
  };
  auto solveCapped = [&](int cap) {
    capped(cap, [&] { last = solveOnce(); });
    iterations += last.iterations;
    residuals();
  };

  // One GNC with thresholds c2: from `start` (first: the current estimate) the plain
  // least-squares solve, then the μ steps; or (fromOdometry) the μ steps straight from the
  // odometry start, μ₀ set by the residuals there.
  auto gncPass = [&](bool first, bool fromOdometry = false) {
    weights_.assign(n, 1.0);
    if (fromOdometry) {
      estimate_.assignFrom(odometryStart);
    } else {
      if (!first) estimate_.assignFrom(start);
      // Plain least squares (all weights 1); capped when the GNC follows (it only starts it).
      capped(anyUncertain ? gnc_.stepIterations : 0, [&] { BatchBackend::optimize(); });
      iterations += summary_.iterations;
      if (first) initialChi2 = summary_.initialChi2;
      last.finalChi2 = summary_.finalChi2;
      last.converged = summary_.converged;
    }
    outer_ = 0;
    if (!anyUncertain) return;
    residuals();
    double maxRatio = 0.0;
    for (int i = 0; i < n; ++i)
      if (c2[i] > 0.0) maxRatio = std::max(maxRatio, r2[i] / c2[i]);
    reason = "max outer iterations";
    if (gnc_.loss == GncLoss::GemanMcClure) {
      mu_ = std::max(1.0, 2.0 * maxRatio);
    } else {
      if (maxRatio <= 1.0) {
        mu_ = 0.0;
        reason = "gnc: every residual below the inlier threshold";
        solveCapped(0);  // every closure in: the plain least squares, to convergence
        return;
      }
      mu_ = std::max(1e-6, 1.0 / (2.0 * maxRatio - 1.0));
    }
    double prevCost = -1.0;
    for (outer_ = 1; outer_ <= gnc_.maxOuterIterations; ++outer_) {
      updateWeights(r2, c2);
      if (!gnc_.warmStart) estimate_.assignFrom(start);
      solveCapped(gnc_.stepIterations);
      const double cost = last.finalWeightedCost;
      if (gnc_.loss == GncLoss::GemanMcClure && mu_ <= 1.0) {
        reason = "gnc: mu reached 1";
        break;
      }
      if (gnc_.loss == GncLoss::TruncatedLeastSquares) {
        bool binary = true;
        for (int i = 0; i < n && binary; ++i)
          binary = weights_[i] < gnc_.weightsTol || weights_[i] > 1.0 - gnc_.weightsTol;
        if (binary) {
          reason = "gnc: weights converged";
          break;
        }
      }
      if (prevCost >= 0.0 &&
          std::abs(cost - prevCost) <= gnc_.relativeCostTol * std::max(prevCost, 1e-12)) {
        reason = "gnc: cost converged";
        break;
      }
      prevCost = cost;
      mu_ =
          gnc_.loss == GncLoss::GemanMcClure ? std::max(1.0, mu_ / gnc_.muStep) : mu_ * gnc_.muStep;
    }
    outer_ = std::min(outer_, gnc_.maxOuterIterations);
    // Report the weights at the final estimate (the last solve moved it); the solve itself
    // used the previous ones, as in GTSAM.
    updateWeights(r2, c2);
  };
  gncPass(true);
  if (!anyUncertain) return;
  const std::string firstReason = reason;
  std::string log;                      // what the candidates did (gncPass overwrites `reason`)
  const std::vector<double> cbar = c2;  // the χ²_dim(p) thresholds
  std::vector<double> gate = c2;        // the thresholds the candidates are judged by
  // The noise-aware gate from the closures the current solution accepts: the tail of their
  // normalized χ² (χ²/χ²_dim(0.5)). It acts (returns true, `out` set) when it is wider (heavy
  // tail, manhattan: out = max(c̄², g·χ²_dim(0.5))) or, with `tighten`, tighter
  // (under-confident information, every g·χ²_dim(0.5) below c̄²/widenFactor: parking-garage,
  // intel; out = g·χ²_dim(0.5)) than c̄² by widenFactor.
  auto estimateGate = [&](std::vector<double>& out) {
    std::vector<double> q;
    for (int i = 0; i < n; ++i)
      if (cbar[i] > 0.0 && weights_[i] >= 0.5)
        q.push_back(r2[i] / chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5));
    const TailGate t = tailGate(q, gnc_.tailExponent, gnc_.medianFactor);
    scale_ = t.scale;
    tailGate_ = t.gate;
    bool wider = false, tighter = t.gate > 0.0 && gnc_.tighten;
    std::vector<double> g(n, 0.0);
    for (int i = 0; i < n; ++i)
      if (cbar[i] > 0.0) {
        g[i] = t.gate * chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5);
        if (std::max(cbar[i], g[i]) > gnc_.widenFactor * cbar[i]) wider = true;
        if (!(g[i] * gnc_.widenFactor < cbar[i])) tighter = false;
      }
    if (wider) {
      out.assign(n, 0.0);
      for (int i = 0; i < n; ++i) out[i] = cbar[i] > 0.0 ? std::max(cbar[i], g[i]) : 0.0;
      return true;
    }
    if (tighter) {
      out = g;
      return true;
    }
    return false;
  };
  bool gated = noiseAware && estimateGate(gate);  // refine, redo with the gate
  // Refinement: decide 0/1 against the gate at the current estimate, re-solve (at most
  // `cap` iterations each), repeat.
  auto refine = [&](int cap) {
    for (int it = 0; it < gnc_.maxRefineIterations; ++it) {
      bool changed = false;
      for (int i = 0; i < n; ++i) {
        if (c2[i] <= 0.0) continue;
        const double w = r2[i] <= gate[i] ? 1.0 : 0.0;
        changed = changed || w != weights_[i];
        weights_[i] = w;
      }
      if (!changed && it > 0) break;
      ++refine_;
      solveCapped(cap);
      if (!changed) break;
    }
  };
  const int refineCap = gnc_.refineIterations;
  // The truncated cost every candidate minimizes: trusted χ² + Σ min(χ², gate).
  auto tlsCost = [&] {
    double cost = 0.0;
    for (int i = 0; i < n; ++i)
      cost += c2[i] > 0.0 ? std::min(r2[i], gate[i]) : graph_[i]->chi2(estimate_);
    return cost;
  };
  struct Candidate {
    double cost;
    Values estimate;
    std::vector<double> weights, r2;
    OptimizerResult last;
  };
  // The current solution (at the current gate's truncated cost), and going back to one.
  auto snapshot = [&] { return Candidate{tlsCost(), estimate_, weights_, r2, last}; };
  auto restore = [&](const Candidate& c) {
    estimate_.assignFrom(c.estimate);
    weights_ = c.weights;
    r2 = c.r2;
    last = c.last;
  };
  auto rejectedCount = [&] {
    int count = 0;
    for (int i = 0; i < n; ++i) count += cbar[i] > 0.0 && weights_[i] < 0.5;
    return count;
  };
  // Every uncertain factor's threshold below its χ²_dim(p) default.
  auto belowDefaults = [&](const std::vector<double>& thresholds) {
    for (int i = 0; i < n; ++i)
      if (cbar[i] > 0.0 && !(thresholds[i] < cbar[i])) return false;
    return true;
  };
  Candidate best;
  std::string bestName, costs;
  auto consider = [&](const std::string& name) {
    Candidate c = snapshot();
    char buf[64];
    std::snprintf(buf, sizeof buf, "%s%s %.6g", costs.empty() ? "" : ", ", name.c_str(), c.cost);
    costs += buf;
    if (bestName.empty() || c.cost < best.cost) {
      best = std::move(c);
      bestName = name;
    }
  };
  // A tightened (or shrunk) gate is usually the median cap (medianFactor × the median): it
  // gets the solution out of bent minima, but true closures' tail can reach beyond it
  // (parking-garage: the largest 208× the median). Once the solution has settled, decide once
  // more against the accepted closures' own tail extrapolation q99·(q99/q90)^tailExponent (no
  // median cap), at most `cap` and at most c̄²/widenFactor (still a tightened gate): rejected
  // closures consistent with the solution come back.
  auto readmitAtTail = [&](double cap) {
    std::vector<double> q;
    for (int i = 0; i < n; ++i)
      if (cbar[i] > 0.0 && weights_[i] >= 0.5)
        q.push_back(r2[i] / chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5));
    const TailGate t = tailGate(q, gnc_.tailExponent, 1e300);
    const double g = std::min(t.gate, cap);
    bool wider = false;
    std::vector<double> next = gate;
    for (int i = 0; i < n; ++i)
      if (cbar[i] > 0.0) {
        next[i] = std::min(g * chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5),
                           cbar[i] / gnc_.widenFactor);
        if (next[i] > gate[i]) wider = true;
      }
    if (wider) {
      const Candidate previous = snapshot();
      const std::vector<double> previousGate = gate;
      gate = next;
      c2 = gate;
      const int before = rejectedCount();
      refine(refineCap);
      const int after = rejectedCount();
      char buf[128];
      std::snprintf(buf, sizeof buf,
                    "; re-check at the tail gate %.3g x chi2_dim(0.5): %d -> %d rejected", g,
                    before, after);
      log += buf;
      if (weights_ == previous.weights) {
        // Nothing came back: the tighter gate, which separated just as well, stands (the
        // wider one would let later checks take in wrong closures that happen to fit a
        // weakly held stretch: intel with 1000 outliers, one or two accepted).
        restore(previous);
        gate = previousGate;
        c2 = gate;
        log += ", gate kept";
        return;
      }
      tailGate_ = g;
    }
  };
  // The gate re-estimated from the current solution; taken (gate and thresholds) if it shrinks
  // by more than widenFactor for every uncertain factor, else nothing changes.
  auto shrinkGate = [&] {
    std::vector<double> next;
    const double usedScale = scale_, usedGate = tailGate_;
    bool shrinks = estimateGate(next);
    for (int i = 0; i < n && shrinks; ++i)
      if (cbar[i] > 0.0) shrinks = next[i] * gnc_.widenFactor < gate[i];
    if (!shrinks) {
      scale_ = usedScale, tailGate_ = usedGate;
      return false;
    }
    gate = next;
    c2 = gate;
    return true;
  };
  const bool odometryCandidate =
      odometryStart.size() == estimate_.size() && odometryStart.size() > 0;
  if (gated || odometryCandidate) {
    // Candidates, the one with the lowest truncated cost kept. A: the first GNC (refined
    // against the gate). B (gate acting, rerunWithGate): the GNC redone from the same start with c̄²
    // = gate — heavy-tailed closures (over-confident information) may have been dropped by the
    // χ²_dim(p) threshold in the non-convex phase. C: the GNC from the odometry start (no
    // least-squares solve with every closure: outliers cannot bend the start), with the same
    // thresholds.
    if (gated) refine(refineCap);
    consider("first");
    const int firstOuter = outer_;
    c2 = gate;
    if (gated && (gnc_.rerunWithGate || !odometryCandidate)) {
      gncPass(false);
      outer_ += firstOuter;
      refine(refineCap);
      consider("redone with the gate");
    }
    if (odometryCandidate) {
      const int before = outer_;
      gncPass(false, true);
      outer_ += before;
      if (gated) refine(refineCap);
      consider("from odometry");
    }
    restore(best);
    log += "; kept " + bestName + " (truncated costs " + costs + ")";
    // The gate was estimated from the first GNC, whose solution outliers may have bent: its
    // accepted closures' tail is then too wide. Re-estimate it from the kept solution; while
    // it shrinks by more than widenFactor, refine the kept solution against it and redo the
    // GNC from the odometry start with it, keep the cheaper (under the new gate).
    int rounds = 0;
    const double firstGate = tailGate_;
    for (int round = 0; gated && round < gnc_.maxGateRounds; ++round) {
      if (!shrinkGate()) break;
      bestName.clear();
      costs.clear();
      refine(refineCap);
      consider("kept, refined");
      if (odometryCandidate) {
        const int before = outer_;
        gncPass(false, true);
        outer_ += before;
        refine(refineCap);
        consider("from odometry");
      }
      restore(best);
      char buf[96];
      std::snprintf(buf, sizeof buf, "; gate re-estimated: %.3g x chi2_dim(0.5), kept ", tailGate_);
      log += buf + bestName + " (" + costs + ")";
      ++rounds;
    }
    const bool tightened = gated && belowDefaults(gate);
    if ((rounds > 0 || tightened) && gnc_.readmit)
      readmitAtTail(rounds > 0 ? firstGate : std::numeric_limits<double>::infinity());
  }
  // The clusters, the drop check and the final gate are for TLS's 0/1 decisions.
  const bool tls = gnc_.loss == GncLoss::TruncatedLeastSquares;
  // Sets the weights of `factors` to `weight`, re-solves, decides against the gate, and keeps
  // the result if the truncated cost dropped (else goes back). Logs what happened as `what`.
  auto tryDecisions = [&](const std::vector<int>& factors, double weight, const char* what,
                          int cap) {
    const Candidate previous = snapshot();
    for (int i : factors) weights_[i] = weight;
    ++refine_;
    solveCapped(cap);
    refine(cap);
    const double after = tlsCost();
    const bool kept = after < previous.cost;
    if (!kept) restore(previous);
    char buf[160];
    std::snprintf(buf, sizeof buf, "; %s: %zu closures, %s (truncated cost %.6g -> %.6g)", what,
                  factors.size(), kept ? "kept" : "dropped", previous.cost, after);
    log += buf;
    return kept;
  };
  const JointMarginalsFn jointMarginal = [this](const std::vector<std::vector<Key>>& sets) {
    return jointMarginals(sets);
  };
  // The uncertain factors the current weights accept (or reject).
  auto uncertainWhere = [&](bool accepted) {
    std::vector<int> out;
    for (int i = 0; i < n; ++i)
      if (cbar[i] > 0.0 && (weights_[i] >= 0.5) == accepted) out.push_back(i);
    return out;
  };
  // The predicted change of the truncated cost per group (NaN: unknown): admitting a rejected
  // group trades its gate terms for the cost rise, rejecting an accepted one trades the cost
  // drop for its gate terms. Negative: worth trying.
  auto predictedNet = [&](const std::vector<std::vector<int>>& groups, GroupChange change) {
    std::vector<double> net = predictedCostChange(graph_, estimate_, groups, change, jointMarginal);
    for (size_t g = 0; g < groups.size(); ++g) {
      double gates = 0.0;
      for (int i : groups[g]) gates += gate[i];
      net[g] = change == GroupChange::Add ? net[g] - gates : gates - net[g];
    }
    return net;
  };
  // Re-check of the rejected closures against the map's own uncertainty: accepting a closure
  // (or a cluster) G raises the cost by about rᵀ(I + JΣJᵀ)⁻¹r (robust/closure_leverage.h)
  // instead of Σ_G gate_i. Those for which that is a net drop are accepted together, kept if
  // the truncated cost did drop (a stiff true closure left out of a locally misfit map:
  // manhattan with 1000 outliers). Clusters too: a stretch held off by wrong closures can be
  // too stiff for one true closure to pull back.
  auto admitFitting = [&](int cap) {
    c2 = gate;
    const std::vector<int> rejectedOnes = uncertainWhere(false);
    std::vector<std::vector<int>> groups;
    for (int i : rejectedOnes) groups.push_back({i});
    if (tls)
      for (auto& c : closureClusters(graph_, estimate_, rejectedOnes, gnc_.admitWindow))
        if (c.size() > 1 && static_cast<int>(c.size()) <= gnc_.maxCluster)
          groups.push_back(std::move(c));
    const std::vector<double> net = predictedNet(groups, GroupChange::Add);
    // The rise (net + the group's gates) within the noise (admitWithinNoise).
    const bool noiseBound = tls && gnc_.admitWithinNoise && noiseAware && scale_ > 0.0;
    auto withinNoise = [&](const std::vector<int>& group, double groupNet) {
      if (!noiseBound) return true;
      double rise = groupNet, bound = 0.0;
      for (int i : group) {
        rise += gate[i];
        bound += gnc_.medianFactor * scale_ * chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5);
      }
      return rise <= bound;
    };
    std::vector<char> take(n, 0);
    for (size_t g = 0; g < groups.size(); ++g)
      if (net[g] < 0.0 && withinNoise(groups[g], net[g]))
        for (int i : groups[g]) take[i] = 1;
    std::vector<int> admit;
    for (int i : rejectedOnes)
      if (take[i]) admit.push_back(i);
    return !admit.empty() && tryDecisions(admit, 1.0, "re-check, rejected that fit", cap);
  };
  // The converse: a few wrong closures that agree with each other can hold the map bent with
  // true closures pushed out (manhattan, a group of 10 with 3 accepted and 2 true ones
  // rejected). Removing an accepted cluster G lowers the cost by rᵀ(I − JΣJᵀ)⁻¹r and adds
  // Σ_G gate_i: clusters for which that is a net drop are rejected together (if that fails,
  // the most promising alone), kept if the truncated cost dropped.
  auto dropBending = [&](int cap) {
    c2 = gate;
    std::vector<std::vector<int>> clusters;
    for (auto& c : closureClusters(graph_, estimate_, uncertainWhere(true), gnc_.dropWindow))
      if (static_cast<int>(c.size()) <= gnc_.maxCluster) clusters.push_back(std::move(c));
    const std::vector<double> net = predictedNet(clusters, GroupChange::Remove);
    std::vector<int> reject;
    int best = -1;
    double bestNet = 0.0;
    for (size_t c = 0; c < clusters.size(); ++c) {
      if (!(net[c] < 0.0)) continue;
      reject.insert(reject.end(), clusters[c].begin(), clusters[c].end());
      if (net[c] < bestNet) bestNet = net[c], best = static_cast<int>(c);
    }
    if (reject.empty()) return false;
    if (tryDecisions(reject, 0.0, "drop check, accepted clusters that bend the map", cap))
      return true;
    return clusters[best].size() < reject.size() &&
           tryDecisions(clusters[best], 0.0, "drop check, the most promising cluster", cap);
  };
  // Each change can make the other possible (a dropped group lets true closures back in).
  // Solves capped at `cap` iterations (0: to convergence).
  auto runChecks = [&](int cap) {
    for (int round = 0; round < gnc_.checkRounds; ++round) {
      const bool admitted = gnc_.recheckRejected && admitFitting(cap);
      const bool dropped = tls && gnc_.dropClusters && dropBending(cap);
      if (!admitted && !dropped) break;
    }
  };
  if (odometryCandidate && gnc_.consistentStart) {
    // Consistent groups of wrong closures can bend the map from both starts (intel, 1000 in
    // groups of 10). If anything is rejected, start once more from the largest pairwise
    // consistent set of closures (PCM) — its linear initialization with the trusted factors —
    // decide 0/1 against the gate there, and keep it if its truncated cost is lower.
    if (rejectedCount() > 0) {
      c2 = gate;
      ConsistencyOptions pcm;
      pcm.probability = gnc_.consistencyProbability;
      std::vector<double> qOdometry, qClosures;
      for (int i = 0; i < n; ++i) {
        const double q = (cbar[i] > 0.0 ? r2[i] : graph_[i]->chi2(estimate_)) /
                         chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5);
        if (graph_[i]->role() == FactorRole::Odometry)
          qOdometry.push_back(q);
        else if (cbar[i] > 0.0 && weights_[i] >= 0.5)
          qClosures.push_back(q);
      }
      pcm.odometryScale = median(qOdometry, 1.0);
      pcm.closureScale = median(qClosures, 1.0);
      const ConsistentSet set = pairwiseConsistentClosures(graph_, odometryStart, pcm);
      const Values consistentStart = set.size > 0 ? trustedLinearStart(set.member) : Values();
      char buf[256];
      if (consistentStart.size() == estimate_.size()) {
        const Candidate kept = snapshot();
        estimate_.assignFrom(consistentStart);
        for (int i = 0; i < n; ++i)
          if (cbar[i] > 0.0) weights_[i] = set.member[i] ? 1.0 : 0.0;
        solveCapped(refineCap);
        // The gate from this (clean) solution's accepted closures, if it acts; adopted with
        // the candidate.
        std::vector<double> candidateGate = gate;
        const double usedScale = scale_, usedGate = tailGate_;
        const bool ownGate = noiseAware && estimateGate(candidateGate);
        // The set is a selection of the best-fitting closures, so its tail understates the
        // true closures' (intel: q99·(q99/q90)³ at 0.04 of χ²_dim(0.5) with the median at
        // 0.003): a tightened gate is not taken below medianFactor × the median.
        if (ownGate)
          for (int i = 0; i < n; ++i)
            if (cbar[i] > 0.0 && candidateGate[i] < cbar[i])
              candidateGate[i] = std::max(
                  candidateGate[i], std::min(cbar[i] / gnc_.widenFactor,
                                             gnc_.medianFactor * scale_ *
                                                 chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5)));
        const double candidateScale = scale_, candidateTail = tailGate_;
        scale_ = usedScale, tailGate_ = usedGate;
        const std::vector<double> keptGate = gate;
        gate = candidateGate;
        refine(refineCap);
        // The same decisions at a cost lower by rounding are not a better answer (taking its
        // gate then cut parking-garage's true tail).
        auto sameDecisions = [&] {
          for (int i = 0; i < n; ++i)
            if (cbar[i] > 0.0 && (weights_[i] >= 0.5) != (kept.weights[i] >= 0.5)) return false;
          return true;
        };
        // First, both at the candidate's own gate if it is tighter (judgeAtOwnGate).
        bool tighterOwn = ownGate && gnc_.judgeAtOwnGate;
        double keptAtOwn = kept.cost;
        for (int i = 0; i < n; ++i)
          if (cbar[i] > 0.0) {
            tighterOwn = tighterOwn && candidateGate[i] * gnc_.widenFactor < keptGate[i];
            keptAtOwn += std::min(kept.r2[i], candidateGate[i]) - std::min(kept.r2[i], keptGate[i]);
          }
        const double atOwn = tlsCost();
        const bool winsAtOwn = tighterOwn && atOwn < keptAtOwn && !sameDecisions();
        if (winsAtOwn) {
          std::snprintf(buf, sizeof buf, "; at its own gate %.3g x chi2_dim(0.5): %.6g vs %.6g",
                        candidateTail, atOwn, keptAtOwn);
          log += buf;
        }
        gate = keptGate;  // both judged by the same truncated cost
        c2 = gate;
        // A set of mutually consistent wrong closures (groups) can join the true ones: the
        // checks can still drop them before the candidate is judged.
        if (!winsAtOwn && !(tlsCost() < kept.cost)) runChecks(refineCap);
        const double after = tlsCost();
        const bool keep = winsAtOwn || (after < kept.cost && !sameDecisions());
        if (keep && ownGate) {
          gate = candidateGate;
          scale_ = candidateScale, tailGate_ = candidateTail;
        }
        if (!keep) restore(kept);
        std::snprintf(buf, sizeof buf,
                      "; from the consistent set (%d of %d closures; scales %.3g, %.3g, "
                      "calibrated x%.3g on %d short cycles): %s (truncated cost %.6g vs %.6g)",
                      set.size, set.judged, pcm.odometryScale, pcm.closureScale, set.calibration,
                      set.calibrationPairs, keep ? "kept" : "dropped", after, kept.cost);
        log += buf;
        if (keep && ownGate && belowDefaults(gate) && gnc_.readmit)
          readmitAtTail(std::numeric_limits<double>::infinity());
      } else {
        std::snprintf(buf, sizeof buf, "; consistent set: %d of %d closures, no start", set.size,
                      set.judged);
        log += buf;
      }
    }
  }
  // The kept solution, solved to convergence (its solves were capped); with the gate acting,
  // its decisions re-made at the converged estimate.
  if (anyUncertain) {
    if (gated)
      refine(0);
    else
      solveCapped(0);
  }
  runChecks(0);
  // The gate once more, from the final solution: if the first was estimated from a bent map
  // and the settled one's closures say it is over twice too wide (intel, 1000 in groups: the
  // consistent-set start kept, the median 10x below the first one's), decide again against
  // it (re-admitting the tail as above) and re-run the checks.
  for (int round = 0; tls && gnc_.regateAtEnd && noiseAware && round < gnc_.maxGateRounds;
       ++round) {
    if (!shrinkGate()) break;
    gated = true;
    refine(0);
    char buf[96];
    std::snprintf(buf, sizeof buf, "; final gate: %.3g x chi2_dim(0.5)", tailGate_);
    log += buf;
    const double shrunk = tailGate_;
    if (gnc_.readmit && belowDefaults(gate)) readmitAtTail(std::numeric_limits<double>::infinity());
    runChecks(0);
    if (tailGate_ != shrunk) break;  // the true tail widened it back: estimating again repeats
  }
  reason = firstReason + log;
  if (noiseAware) {
    char buf[160];
    std::snprintf(buf, sizeof buf,
                  "; noise scale %.3g, tail gate %.3g x chi2_dim(0.5)%s, %d refinement solves",
                  scale_, tailGate_, gated ? " (acting)" : "", refine_);
    reason += buf;
  }
  summary_.iterations = iterations;
  summary_.initialChi2 = initialChi2;
  summary_.finalChi2 = last.finalChi2;
  summary_.converged = last.converged;
  summary_.stopReason = reason;
}

std::vector<std::pair<FactorId, double>> GncBackend::decisions() const {
  std::vector<std::pair<FactorId, double>> out;
  const bool have = weights_.size() == static_cast<size_t>(graph_.size());
  for (int i = 0; i < graph_.size(); ++i)
    if (isUncertain(graph_[i]->role())) out.emplace_back(graph_[i]->id(), have ? weights_[i] : 1.0);
  return out;
}

std::vector<FactorId> GncBackend::rejected() const {
  std::vector<FactorId> out;
  const double below = gnc_.rejectBelow > 0.0               ? gnc_.rejectBelow
                       : gnc_.loss == GncLoss::GemanMcClure ? 0.25
                                                            : 0.5;
  for (const auto& [id, w] : decisions())
    if (w < below) out.push_back(id);
  return out;
}

}  // namespace loopd
