// optimize()'s fallback (heldDescent) where a full Gauss–Newton step went uphill and some
// factor re-weights its residual. The plain fallback, Levenberg–Marquardt on the whole graph,
// minimises rᵀr; a max-mixture's rᵀr falls to ~0 for a closure pushed past its switch point,
// so that fallback can end with true closures rejected wholesale (three robots on
// parking-garage + 100 wrong closures: every closure between them). This one minimises the
// objective itself, by majorization–minimization: a robust factor held as at x bounds its
// objective from above and touches it at x, so each solve that lowers the held least
// squares lowers the objective, and every closure is judged again at the new estimate.
#include <algorithm>
#include <array>

#include "solvers/batch/nonlinear_optimizer.h"
#include "solvers/incremental/isam2.h"

namespace loopd {

namespace {
// Levenberg–Marquardt iterations per held solve: closures are judged again after each, so a
// rejected one that the map came back to rejoins before the solve has settled without it.
constexpr int kHeldSolveIterations = 10;
}  // namespace

bool Isam2Backend::heldDescent(int budget, double& previous, int& iterations) {
  FactorGraph held;
  std::vector<double> weights, heldBefore;
  held.reserve(static_cast<size_t>(graph_.size()) + 1);
  weights.reserve(static_cast<size_t>(graph_.size()) + 1);
  std::array<const double*, kMaxFactorKeys> x{};
  double lambda = OptimizerOptions{}.initialLambda;
  std::vector<char> fixed;
  bool anyHeld = false;
  while (iterations < budget) {
    held.factors().clear();
    heldBefore.swap(weights);
    weights.clear();
    auto add = [&](const FactorPtr& f) {
      for (int k = 0; k < f->size(); ++k)
        x[static_cast<size_t>(k)] = estimate_.data(estimate_.slot(f->key(k)));
      FactorPtr inner;
      double w = 1.0;
      const bool isHeld = f->heldAt(x.data(), inner, w);
      anyHeld = anyHeld || isHeld;
      held.add(isHeld ? inner : f);
      weights.push_back(w);
    };
    for (const FactorPtr& f : graph_.factors()) add(f);
    if (gaugeFactor_ >= 0) add(factors_[gaugeFactor_]);
    if (!anyHeld) return false;  // least squares: the caller's plain LM minimises the objective
    if (fixed.empty()) fixed = fixedForBatch();
    OptimizerOptions o;
    o.method = OptimizerMethod::LevenbergMarquardt;
    o.maxIterations = std::min(kHeldSolveIterations, budget - iterations);
    o.initialLambda = lambda;  // the damping carried from one held solve to the next
    NonlinearOptimizer lm(held, estimate_, fixed, o);
    const Values before = estimate_;
    const OptimizerResult r = lm.optimize(estimate_, weights.data());
    iterations += std::max(r.iterations, 1);
    if (r.finalTrustParameter > 0.0) lambda = r.finalTrustParameter;
    const double current = costWithGauge();
    if (!(current < previous)) {
      estimate_ = before;
      return true;
    }
    const double gain = previous - current;
    previous = current;
    const bool settled = weights == heldBefore;  // every factor held as in the last solve
    if (gain <= isam_.finalRelativeTolerance * current + 1e-14 || (settled && r.converged))
      return true;
  }
  return true;
}

}  // namespace loopd
