#include "solvers/batch/nonlinear_optimizer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>

namespace loopd {

namespace {

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

double dot(const std::vector<double>& a, const std::vector<double>& b) {
  double s = 0.0;
  for (size_t i = 0; i < a.size(); ++i) s += a[i] * b[i];
  return s;
}

}  // namespace

OptimizerMethod optimizerMethodFromName(const std::string& name) {
  if (name == "gn") return OptimizerMethod::GaussNewton;
  if (name == "lm") return OptimizerMethod::LevenbergMarquardt;
  if (name == "dogleg") return OptimizerMethod::Dogleg;
  throw std::invalid_argument("unknown optimizer method '" + name + "' (gn, lm, dogleg)");
}

const char* optimizerMethodName(OptimizerMethod m) {
  switch (m) {
    case OptimizerMethod::GaussNewton:
      return "gn";
    case OptimizerMethod::LevenbergMarquardt:
      return "lm";
    case OptimizerMethod::Dogleg:
      return "dogleg";
  }
  return "?";
}

void symmetricMultiply(const HessianLayout& layout, const std::vector<double>& A,
                       const std::vector<double>& x, std::vector<double>& y) {
  const int n = layout.dimension();
  const auto& cs = layout.columnStart();
  const auto& ri = layout.rowIndex();
  y.assign(n, 0.0);
  for (int j = 0; j < n; ++j) {
    double yj = 0.0;
    const double xj = x[j];
    for (int p = cs[j]; p < cs[j + 1]; ++p) {
      const int i = ri[p];
      if (i > j) break;  // rows are sorted; the rest is the ignored lower part
      y[i] += A[p] * xj;
      if (i != j) yj += A[p] * x[i];
    }
    y[j] += yj;
  }
}

NonlinearOptimizer::NonlinearOptimizer(const FactorGraph& graph, const Values& values,
                                       std::vector<char> fixedSlots, OptimizerOptions options)
    : graph_(graph),
      options_(std::move(options)),
      fixedSlots_(std::move(fixedSlots)),
      layout_(graph, values, fixedSlots_),
      bufferA_(layout_),
      bufferB_(layout_),
      cholesky_(options_.factorization) {
  cholesky_.analyze(layout_);
}

void NonlinearOptimizer::report(int iteration, const LinearizationCost& cost, double trust,
                                bool accepted, double seconds) const {
  if (!options_.progress) return;
  IterationReport r;
  r.iteration = iteration;
  r.chi2 = cost.chi2;
  r.weightedCost = cost.weighted;
  r.trustParameter = trust;
  r.accepted = accepted;
  r.seconds = seconds;
  options_.progress(r);
}

bool NonlinearOptimizer::stepIsNegligible(const std::vector<double>& step) const {
  double stepNorm2 = 0.0;
  for (double v : step) stepNorm2 += v * v;
  return std::sqrt(stepNorm2) < options_.stepTolerance * std::sqrt(step.size() + 1.0);
}

bool NonlinearOptimizer::remainingDecreaseNegligible(double cost, std::vector<double>& work,
                                                     std::vector<double>& solution) {
  // gᵀH⁻¹g is what the next Gauss–Newton step would gain; the previous factorization is
  // close enough to H here to tell "nothing left" without paying for a new one. Without one
  // (Dogleg's Cauchy-point steps on a singular H) it cannot be told.
  if (!cholesky_.factorized()) return false;
  const std::vector<double>& g = current_->gradient();
  work = g;
  cholesky_.solve(work.data(), solution.data());
  const double expected = dot(solution, g);
  return expected >= 0.0 && expected <= options_.relativeTolerance * cost;
}

void NonlinearOptimizer::fitPattern(const Values& values, const double* weights) {
  const int n = graph_.size();
  auto wanted = [&](int f) { return !weights || weights[f] != 0.0; };
  bool same = true;
  for (int f = 0; f < n && same; ++f) same = wanted(f) == layout_.isActive(f);
  if (same) return;
  std::vector<char> active;  // empty: every factor
  if (weights) {
    active.resize(n);
    for (int f = 0; f < n; ++f) active[f] = wanted(f);
  }
  layout_ = HessianLayout(graph_, values, fixedSlots_, active);
  bufferA_.fitLayout();
  bufferB_.fitLayout();
  cholesky_.analyze(layout_);
}

bool NonlinearOptimizer::factorizeAt(const Values& values, const double* weights) {
  fitPattern(values, weights);
  current_->build(graph_, values, weights);
  return cholesky_.factorize(current_->hessian());
}

OptimizerResult NonlinearOptimizer::optimize(Values& values, const double* weights) {
  fitPattern(values, weights);
  if (layout_.dimension() == 0) {
    OptimizerResult r;
    r.initialChi2 = r.finalChi2 = current_->cost(graph_, values, weights).chi2;
    r.converged = true;
    r.stopReason = "no free variables";
    return r;
  }
  switch (options_.method) {
    case OptimizerMethod::GaussNewton:
      return runGaussNewton(values, weights);
    case OptimizerMethod::LevenbergMarquardt:
      return runLevenbergMarquardt(values, weights);
    case OptimizerMethod::Dogleg:
      return runDogleg(values, weights);
  }
  throw std::logic_error("unknown optimizer method");
}

namespace {

// Convergence on the cost decrease of an accepted step.
bool costConverged(double before, double after, const OptimizerOptions& o) {
  const double decrease = before - after;
  return decrease <= o.absoluteTolerance || decrease <= o.relativeTolerance * before;
}

}  // namespace

const char* NonlinearOptimizer::acceptStep(Values& values, const Values& trialValues,
                                           const LinearizationCost& trialCost,
                                           LinearizationCost& cost, std::vector<double>& step,
                                           std::vector<double>& work) {
  const double before = cost.weighted;
  values.assignFrom(trialValues);
  std::swap(current_, trial_);
  cost = trialCost;
  if (costConverged(before, cost.weighted, options_)) return "cost decrease below tolerance";
  if (stepIsNegligible(step)) return "step below tolerance";
  if (remainingDecreaseNegligible(cost.weighted, work, step))
    return "expected decrease below tolerance";
  return nullptr;
}

namespace {

OptimizerResult& finish(OptimizerResult& result, const LinearizationCost& cost) {
  if (result.stopReason.empty()) {
    result.stopReason = "iteration limit";
    result.budgetSpent = true;
  }
  result.finalChi2 = cost.chi2;
  result.finalWeightedCost = cost.weighted;
  return result;
}

}  // namespace

OptimizerResult NonlinearOptimizer::runLevenbergMarquardt(Values& values, const double* weights) {
  const int n = layout_.dimension();
  const auto& diagPos = layout_.diagonalPositions();
  OptimizerResult result;
  LinearizationCost cost = current_->build(graph_, values, weights);
  result.initialChi2 = cost.chi2;
  double lambda = options_.initialLambda, nu = 2.0;
  std::vector<double> diag(n), step(n), rhs(n);
  Values trialValues = values;

  for (int it = 1; it <= options_.maxIterations; ++it) {
    const auto t0 = Clock::now();
    result.iterations = it;
    std::vector<double>& H = current_->hessian();
    const std::vector<double>& g = current_->gradient();
    for (int i = 0; i < n; ++i) diag[i] = std::clamp(H[diagPos[i]], 1e-6, 1e32);
    for (int i = 0; i < n; ++i) rhs[i] = -g[i];

    // (H + λD)δ = −g; D = diag(H) clamped (Marquardt's scaling).
    for (int i = 0; i < n; ++i) H[diagPos[i]] += lambda * diag[i];
    const bool factored = cholesky_.factorize(H);
    for (int i = 0; i < n; ++i) H[diagPos[i]] -= lambda * diag[i];
    if (!factored) {
      lambda *= nu;
      nu *= 2.0;
      report(it, cost, lambda, false, secondsSince(t0));
      if (lambda > 1e32) {
        result.stopReason = "damping exploded (Hessian not positive definite)";
        break;
      }
      continue;
    }
    cholesky_.solve(rhs.data(), step.data());

    // Predicted decrease of rᵀr: −2δᵀg − δᵀHδ = −δᵀg + λ Σ Dᵢδᵢ².
    double damped = 0.0;
    for (int i = 0; i < n; ++i) damped += diag[i] * step[i] * step[i];
    const double predicted = -dot(step, g) + lambda * damped;

    trialValues.assignFrom(values);
    trialValues.retractAll(layout_.slotOffset(), step.data());
    const LinearizationCost trialCost = trial_->build(graph_, trialValues, weights);
    const double actual = cost.weighted - trialCost.weighted;
    const double rho = predicted > 0.0 ? actual / predicted : -1.0;

    if (rho > 1e-3 && std::isfinite(trialCost.weighted)) {
      lambda *= std::max(1.0 / 3.0, 1.0 - std::pow(2.0 * rho - 1.0, 3));
      lambda = std::max(lambda, 1e-12);
      nu = 2.0;
      const char* stop = acceptStep(values, trialValues, trialCost, cost, step, rhs);
      report(it, cost, lambda, true, secondsSince(t0));
      if (stop) {
        result.converged = true;
        result.stopReason = stop;
        break;
      }
    } else {
      lambda *= nu;
      nu *= 2.0;
      report(it, cost, lambda, false, secondsSince(t0));
      if (predicted >= 0.0 && predicted <= options_.relativeTolerance * cost.weighted) {
        // Even the model promises nothing worth having: we are at the minimum to rounding.
        result.converged = true;
        result.stopReason = "predicted decrease below tolerance";
        break;
      }
      if (lambda > 1e32) {
        result.converged = true;  // no decrease possible: at a minimum to rounding
        result.stopReason = "no further decrease possible";
        break;
      }
    }
  }
  result.finalTrustParameter = lambda;
  return finish(result, cost);
}

OptimizerResult NonlinearOptimizer::runGaussNewton(Values& values, const double* weights) {
  const int n = layout_.dimension();
  OptimizerResult result;
  LinearizationCost cost = current_->build(graph_, values, weights);
  result.initialChi2 = cost.chi2;
  std::vector<double> step(n), rhs(n);
  Values trialValues = values;
  for (int it = 1; it <= options_.maxIterations; ++it) {
    const auto t0 = Clock::now();
    result.iterations = it;
    if (!cholesky_.factorize(current_->hessian())) {
      result.stopReason = "Hessian not positive definite";
      break;
    }
    const auto& g = current_->gradient();
    for (int i = 0; i < n; ++i) rhs[i] = -g[i];
    cholesky_.solve(rhs.data(), step.data());
    trialValues.assignFrom(values);
    trialValues.retractAll(layout_.slotOffset(), step.data());
    const LinearizationCost trialCost = trial_->build(graph_, trialValues, weights);
    if (!(trialCost.weighted <= cost.weighted)) {
      // Gauss–Newton has no safeguard; stop rather than go uphill.
      report(it, cost, 0.0, false, secondsSince(t0));
      result.stopReason = "step increased the cost";
      result.converged = cost.weighted - trialCost.weighted >= -1e-9 * cost.weighted;
      break;
    }
    const char* stop = acceptStep(values, trialValues, trialCost, cost, step, rhs);
    report(it, cost, 0.0, true, secondsSince(t0));
    if (stop) {
      result.converged = true;
      result.stopReason = stop;
      break;
    }
  }
  return finish(result, cost);
}

OptimizerResult NonlinearOptimizer::runDogleg(Values& values, const double* weights) {
  const int n = layout_.dimension();
  OptimizerResult result;
  LinearizationCost cost = current_->build(graph_, values, weights);
  result.initialChi2 = cost.chi2;
  double radius = options_.initialRadius;
  std::vector<double> gaussNewton(n), steepest(n), step(n), rhs(n), Hg(n), Hh(n);
  Values trialValues = values;
  bool haveSteps = false;

  for (int it = 1; it <= options_.maxIterations; ++it) {
    const auto t0 = Clock::now();
    result.iterations = it;
    const std::vector<double>& H = current_->hessian();
    const std::vector<double>& g = current_->gradient();
    if (!haveSteps) {
      // Steepest descent minimiser along −g and the Gauss–Newton point, once per linearization.
      symmetricMultiply(layout_, H, g, Hg);
      const double gg = dot(g, g), gHg = dot(g, Hg);
      const double alpha = gHg > 0.0 ? gg / gHg : 0.0;
      for (int i = 0; i < n; ++i) steepest[i] = -alpha * g[i];
      if (cholesky_.factorize(H)) {
        for (int i = 0; i < n; ++i) rhs[i] = -g[i];
        cholesky_.solve(rhs.data(), gaussNewton.data());
      } else {
        gaussNewton = steepest;  // singular: fall back to the Cauchy point
      }
      haveSteps = true;
    }
    const double gnNorm = std::sqrt(dot(gaussNewton, gaussNewton));
    const double sdNorm = std::sqrt(dot(steepest, steepest));
    if (gnNorm <= radius) {
      step = gaussNewton;
    } else if (sdNorm >= radius) {
      for (int i = 0; i < n; ++i) step[i] = steepest[i] * (radius / sdNorm);
    } else {
      // β with |sd + β(gn − sd)| = radius.
      double a = 0.0, b = 0.0, c = 0.0;
      for (int i = 0; i < n; ++i) {
        const double d = gaussNewton[i] - steepest[i];
        a += d * d;
        b += 2.0 * steepest[i] * d;
        c += steepest[i] * steepest[i];
      }
      c -= radius * radius;
      const double beta = (-b + std::sqrt(std::max(0.0, b * b - 4.0 * a * c))) / (2.0 * a);
      for (int i = 0; i < n; ++i) step[i] = steepest[i] + beta * (gaussNewton[i] - steepest[i]);
    }
    symmetricMultiply(layout_, H, step, Hh);
    const double predicted = -2.0 * dot(step, g) - dot(step, Hh);
    trialValues.assignFrom(values);
    trialValues.retractAll(layout_.slotOffset(), step.data());
    const LinearizationCost trialCost = trial_->build(graph_, trialValues, weights);
    const double actual = cost.weighted - trialCost.weighted;
    const double rho = predicted > 0.0 ? actual / predicted : -1.0;
    const double stepNorm = std::sqrt(dot(step, step));
    if (rho > 0.75) radius = std::max(radius, 3.0 * stepNorm);
    if (rho < 0.25) radius = 0.5 * stepNorm;

    if (rho > 1e-3 && std::isfinite(trialCost.weighted)) {
      // The last factorization is of H itself here, so the expected-decrease test is exact.
      const char* stop = acceptStep(values, trialValues, trialCost, cost, step, rhs);
      haveSteps = false;
      report(it, cost, radius, true, secondsSince(t0));
      if (stop) {
        result.converged = true;
        result.stopReason = stop;
        break;
      }
    } else {
      report(it, cost, radius, false, secondsSince(t0));
      if (radius < 1e-12) {
        result.converged = true;
        result.stopReason = "trust region collapsed: no further decrease possible";
        break;
      }
    }
  }
  return finish(result, cost);
}

}  // namespace loopd
