#include "robust/gnc_backend.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "robust/robust_factors.h"
#include "solvers/init/initialization.h"

namespace loopd {

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
  weights_.assign(n, 1.0);
  const Values start = estimate_;
  BatchBackend::optimize();  // plain least squares (all weights 1)
  int iterations = summary_.iterations;
  const double initialChi2 = summary_.initialChi2;

  std::vector<double> r2(n, 0.0), c2(n, 0.0);
  auto residuals = [&] {
    for (int i = 0; i < n; ++i)
      if (c2[i] > 0.0) r2[i] = graph_[i]->chi2(estimate_);
  };
  bool anyUncertain = false;
  for (int i = 0; i < n; ++i)
    if (isUncertain(graph_[i]->role())) c2[i] = barc2(*graph_[i]), anyUncertain = true;
  outer_ = 0;
  if (!anyUncertain) return;
  residuals();
  double maxRatio = 0.0;
  for (int i = 0; i < n; ++i)
    if (c2[i] > 0.0) maxRatio = std::max(maxRatio, r2[i] / c2[i]);

  std::string reason = "max outer iterations";
  if (gnc_.loss == GncLoss::GemanMcClure) {
    mu_ = std::max(1.0, 2.0 * maxRatio);
  } else {
    if (maxRatio <= 1.0) {
      mu_ = 0.0;
      summary_.stopReason = "gnc: every residual below the inlier threshold";
      return;
    }
    mu_ = std::max(1e-6, 1.0 / (2.0 * maxRatio - 1.0));
  }

  double prevCost = -1.0;
  OptimizerResult last;
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
  // Report the weights at the final estimate (the last solve moved it); the solve itself used
  // the previous ones, as in GTSAM.
  updateWeights(r2, c2);
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
