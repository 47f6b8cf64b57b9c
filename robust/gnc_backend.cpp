#include "robust/gnc_backend.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

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
      if (r <= lower) weights_[i] = 1.0;
      else if (r >= upper) weights_[i] = 0.0;
      else weights_[i] = std::clamp(std::sqrt(c / r) * std::sqrt(mu_ * (mu_ + 1.0)) - mu_, 0.0, 1.0);
    }
  }
}

void GncBackend::optimize() {
  if (graph_.empty()) return;
  if (firstSolve_ && options_.linearInitialization && gnc_.trustedInitialization) {
    // Linear initialization from the trusted factors only; the base class must not redo it
    // with the outliers included.
    FactorGraph trusted;
    for (const auto& f : graph_.factors())
      if (!isUncertain(f->role())) trusted.add(f);
    Key anchor = 0;
    bool found = false;
    for (int s = 0; s < estimate_.size(); ++s)
      if (keyKind(estimate_.key(s)) == KeyKind::Pose && (!found || estimate_.key(s) < anchor))
        anchor = estimate_.key(s), found = true;
    if (found && !trusted.empty()) estimate_ = initializeLinear(trusted, estimate_, anchor);
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

  // One GNC from `start` with thresholds c2: the plain least-squares solve, then the μ steps.
  auto gncPass = [&](bool first) {
    weights_.assign(n, 1.0);
    if (!first) estimate_.assignFrom(start);
    BatchBackend::optimize();  // plain least squares (all weights 1)
    iterations += summary_.iterations;
    if (first) initialChi2 = summary_.initialChi2;
    last.finalChi2 = summary_.finalChi2;
    last.converged = summary_.converged;
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
        return;
      }
      mu_ = std::max(1e-6, 1.0 / (2.0 * maxRatio - 1.0));
    }
    double prevCost = -1.0;
    for (outer_ = 1; outer_ <= gnc_.maxOuterIterations; ++outer_) {
      updateWeights(r2, c2);
      if (!gnc_.warmStart) estimate_.assignFrom(start);
      last = solveOnce();
      iterations += last.iterations;
      residuals();
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
      mu_ = gnc_.loss == GncLoss::GemanMcClure ? std::max(1.0, mu_ / gnc_.muStep)
                                               : mu_ * gnc_.muStep;
    }
    outer_ = std::min(outer_, gnc_.maxOuterIterations);
    // Report the weights at the final estimate (the last solve moved it); the solve itself
    // used the previous ones, as in GTSAM.
    updateWeights(r2, c2);
  };
  gncPass(true);
  if (!anyUncertain) return;
  if (noiseAware) {
    // The tail of the accepted closures' normalized χ² (χ²/χ²_dim(0.5)) decides the gate.
    std::vector<double> q;
    for (int i = 0; i < n; ++i)
      if (c2[i] > 0.0 && weights_[i] >= 0.5)
        q.push_back(r2[i] / chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5));
    const TailGate t = tailGate(q, gnc_.tailExponent, gnc_.medianFactor);
    scale_ = t.scale;
    tailGate_ = t.gate;
    // Wider (heavy tail, manhattan) or tighter (under-confident information: every gate below
    // c̄²/widenFactor, parking-garage, intel) than the χ²_dim(p) default by widenFactor.
    bool wider = false, tighter = t.gate > 0.0 && gnc_.tighten;
    std::vector<double> gate(n, 0.0);
    for (int i = 0; i < n; ++i)
      if (c2[i] > 0.0) {
        const double g = t.gate * chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5);
        gate[i] = std::max(c2[i], g);
        if (gate[i] > gnc_.widenFactor * c2[i]) wider = true;
        if (!(g * gnc_.widenFactor < c2[i])) tighter = false;
      }
    if (!wider && tighter) {
      for (int i = 0; i < n; ++i)
        if (c2[i] > 0.0) gate[i] = t.gate * chi2Quantile(std::max(graph_[i]->dim(), 1), 0.5);
      wider = true;  // same procedure: refine, redo with the gate, keep the cheaper
    }
    // Refinement: decide 0/1 against the gate at the current estimate, re-solve, repeat.
    auto refine = [&] {
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
        last = solveOnce();
        iterations += last.iterations;
        residuals();
        if (!changed) break;
      }
    };
    // The truncated cost both candidates minimize: trusted χ² + Σ min(χ², gate).
    auto tlsCost = [&] {
      double cost = 0.0;
      for (int i = 0; i < n; ++i)
        cost += c2[i] > 0.0 ? std::min(r2[i], gate[i]) : graph_[i]->chi2(estimate_);
      return cost;
    };
    if (wider) {
      // Heavy-tailed closures (over-confident information): the χ²_dim(p) threshold may have
      // dropped true closures in the GNC's non-convex phase. Candidate A: this GNC refined
      // against the gate; candidate B: the GNC redone with c̄² = gate, refined. Keep the one
      // with the lower truncated cost.
      refine();
      const double costA = tlsCost();
      const Values estimateA = estimate_;
      const std::vector<double> weightsA = weights_, r2A = r2;
      const OptimizerResult lastA = last;
      c2 = gate;
      const int firstOuter = outer_;
      gncPass(false);
      outer_ += firstOuter;
      refine();
      const double costB = tlsCost();
      if (costA < costB) {
        estimate_.assignFrom(estimateA);
        weights_ = weightsA;
        r2 = r2A;
        last = lastA;
        reason += "; GNC with the noise-aware gate tried, refined first GNC kept";
      } else {
        reason += "; redone with the noise-aware gate";
      }
      char cbuf[96];
      std::snprintf(cbuf, sizeof cbuf, " (truncated cost %.6g vs %.6g)", costA, costB);
      reason += cbuf;
    }
    char buf[128];
    std::snprintf(buf, sizeof buf, "; noise scale %.3g, tail gate %.3g x chi2_dim(0.5), %d refinement solves",
                  scale_, tailGate_, refine_);
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
  const double below = gnc_.rejectBelow > 0.0 ? gnc_.rejectBelow
                       : gnc_.loss == GncLoss::GemanMcClure ? 0.25 : 0.5;
  for (const auto& [id, w] : decisions())
    if (w < below) out.push_back(id);
  return out;
}

}  // namespace loopd
