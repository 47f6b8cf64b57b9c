// iSAM2's updates: variable, factor and gauge bookkeeping, fluid relinearization, update() and
// the final convergence (optimize()). The top's re-elimination is in isam2_recompute.cpp, the
// clique numerics in isam2_cliques.cpp, the marginals in isam2_marginals.cpp.
#include "solvers/incremental/isam2.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <unordered_set>

#include "solvers/backend/update_validation.h"
#include "solvers/batch/nonlinear_optimizer.h"
#include "solvers/factors/prior_factors.h"
#include "solvers/problem/initial_guess.h"

namespace loopd {

namespace {

constexpr FactorId kGaugeFactorId = std::numeric_limits<FactorId>::max();

}  // namespace

Isam2Backend::Isam2Backend(BackendOptions options, Isam2Options isam)
    : options_(std::move(options)), isam_(isam) {
  if (isam_.relinearizeSkip < 1) isam_.relinearizeSkip = 1;
}

// ---------------------------------------------------------------------------------------------
// Bookkeeping

int Isam2Backend::addVariable(const Values& from, int slot) {
  const int v = theta_.insertFrom(from, slot);
  estimate_.insertFrom(from, slot);
  dims_.push_back(varDim(theta_.type(v)));
  cliqueOf_.push_back(-1);
  delta_.resize(delta_.size() + kMaxVarDim, 0.0);
  varFactors_.emplace_back();
  affectedStamp_.push_back(-1);
  changedStamp_.push_back(-1);
  relinCandidate_.push_back(0);
  scratchPos_.push_back(-1);
  localIdx_.push_back(-1);
  constrainedStamp_.push_back(-1);
  movedStamp_.push_back(-1);
  guardStamp_.push_back(-1);
  guardIndex_.push_back(-1);
  touched_.push_back(updateCount_);
  if (firstPose_ < 0 && keyKind(theta_.key(v)) == KeyKind::Pose &&
      (theta_.type(v) == VarType::SE2 || theta_.type(v) == VarType::SE3))
    firstPose_ = v;
  newestVar_ = v;
  return v;
}

void Isam2Backend::markAffected(int v) {
  if (affectedStamp_[v] == epoch_) return;
  affectedStamp_[v] = epoch_;
  affected_.push_back(v);
}

int Isam2Backend::addFactor(const FactorPtr& f) {
  const int index = static_cast<int>(factors_.size());
  factors_.push_back(f);
  std::array<int, kMaxFactorKeys> vars;
  vars.fill(-1);
  for (int k = 0; k < f->size(); ++k) {
    const int v = estimate_.slot(f->key(k));
    vars[k] = v;
    varFactors_[v].push_back(index);
    markAffected(v);
  }
  factorVars_.push_back(vars);
  factorStamp_.push_back(-1);
  guardFactorStamp_.push_back(-1);
  return index;
}

void Isam2Backend::removeFactor(int index) {
  const Factor& f = *factors_[index];
  for (int k = 0; k < f.size(); ++k) {
    const int v = factorVars_[index][k];
    auto& list = varFactors_[v];
    list.erase(std::find(list.begin(), list.end(), index));
    markAffected(v);
  }
  factors_[index].reset();
}

void Isam2Backend::manageGauge() {
  if (priorCount_ == 0 && gaugeFactor_ < 0 && firstPose_ >= 0) {
    const int v = firstPose_;
    FactorPtr prior;
    if (estimate_.type(v) == VarType::SE2)
      prior = std::make_shared<PriorFactorSE2>(
          estimate_.key(v), estimate_.se2(v), isam_.gaugeInformation * Eigen::Matrix3d::Identity());
    else
      prior = std::make_shared<PriorFactorSE3>(estimate_.key(v), estimate_.se3(v),
                                               isam_.gaugeInformation * Mat6::Identity());
    std::const_pointer_cast<Factor>(prior)->setId(kGaugeFactorId);
    std::const_pointer_cast<Factor>(prior)->setRole(FactorRole::Prior);
    gaugeFactor_ = addFactor(prior);
  } else if (priorCount_ > 0 && gaugeFactor_ >= 0) {
    removeFactor(gaugeFactor_);
    gaugeFactor_ = -1;
  }
}

double Isam2Backend::deltaMax(int v) const {
  const double* d = &delta_[static_cast<size_t>(v) * kMaxVarDim];
  double m = 0.0;
  for (int i = 0; i < dims_[v]; ++i) m = std::max(m, std::abs(d[i]));
  return m;
}

void Isam2Backend::relinearizeAtEstimate(int v) {
  // θ ← θ ⊕ Δ is exactly the current estimate; Δ restarts from zero.
  std::memcpy(theta_.data(v), estimate_.data(v), sizeof(double) * kValueStride);
  std::fill_n(&delta_[static_cast<size_t>(v) * kMaxVarDim], kMaxVarDim, 0.0);
  ++stats_.relinearized;
}

void Isam2Backend::markWithItsFactors(int v) {
  // Every factor on v changes its linearization: the cliques holding those factors (the
  // clique of the factor's first-eliminated variable) must be re-eliminated.
  markAffected(v);
  for (int f : varFactors_[v])
    for (int k = 0; k < factors_[f]->size(); ++k) markAffected(factorVars_[f][k]);
}

void Isam2Backend::relinearize(bool all) {
  if (all) {
    for (int v = 0; v < theta_.size(); ++v) {
      relinCandidate_[v] = 0;
      if (varFactors_[v].empty()) continue;
      relinearizeAtEstimate(v);
      markAffected(v);
    }
    relinCandidates_.clear();
    return;
  }
  for (int v : relinCandidates_) {
    relinCandidate_[v] = 0;
    if (cliqueOf_[v] < 0 || deltaMax(v) < isam_.relinearizeThreshold) continue;
    relinearizeAtEstimate(v);
    markWithItsFactors(v);
  }
  relinCandidates_.clear();
}

// ---------------------------------------------------------------------------------------------
// Update

UpdateResult Isam2Backend::update(const BackendUpdate& u) {
  const auto t0 = std::chrono::steady_clock::now();
  // Complete the initial values (odometry composition), then validate before any change.
  Values guess = u.initial;
  predictMissingValues(u.factors, estimate_, guess);
  validateUpdate(u, estimate_, idIndex_, guess);

  ++epoch_;
  ++updateCount_;
  stats_ = {};
  affected_.clear();
  UpdateResult result;

  for (int s = 0; s < guess.size(); ++s) {
    const int v = addVariable(guess, s);
    movedStamp_[v] = epoch_;
    result.moved.push_back(estimate_.key(v));
  }
  if (!u.removals.empty()) {
    std::unordered_set<FactorId> removed(u.removals.begin(), u.removals.end());
    for (FactorId id : u.removals) {
      const auto it = idIndex_.find(id);
      if (factors_[it->second]->role() == FactorRole::Prior) --priorCount_;
      removeFactor(it->second);
      idIndex_.erase(it);
    }
    FactorGraph kept;
    kept.reserve(graph_.size());
    for (const auto& f : graph_.factors())
      if (!removed.count(f->id())) kept.add(f);
    graph_ = std::move(kept);
  }
  for (const auto& f : u.factors) {
    const int index = addFactor(f);
    idIndex_[f->id()] = index;
    graph_.add(f);
    if (f->role() == FactorRole::Prior) ++priorCount_;
    for (int k = 0; k < f->size(); ++k) {
      constrainedStamp_[factorVars_[index][k]] = epoch_;
      touched_[factorVars_[index][k]] = updateCount_;
    }
  }
  manageGauge();
  if (relinearizeNext_ || updateCount_ % isam_.relinearizeSkip == 0) relinearize(false);
  relinearizeNext_ = false;
  result.relinearized = stats_.relinearized;

  recompute();
  guardVars_.clear();
  guardBefore_.clear();
  guarding_ = isam_.guardSteps;  // update()'s step only: optimize() judges its own steps
  backSubstitute(&result.moved);
  if (guarding_) guardStep();
  guarding_ = false;

  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

// ---------------------------------------------------------------------------------------------
// Converging: full relinearization until the cost stops decreasing

void Isam2Backend::relinearizeAllAtEstimate() {
  ++epoch_;
  stats_ = {};
  affected_.clear();
  relinearize(true);
  if (newestVar_ >= 0) constrainedStamp_[newestVar_] = epoch_;
  recompute();
}

void Isam2Backend::resetEstimate(const Values& x) {
  for (int v = 0; v < estimate_.size(); ++v) {
    const int s = x.slot(estimate_.key(v));
    if (s >= 0) std::memcpy(estimate_.data(v), x.data(s), sizeof(double) * kValueStride);
  }
  relinearizeAllAtEstimate();
}

double Isam2Backend::costWithGauge() const {
  // The objective, not rᵀr: a max-mixture's rᵀr drops when a closure passes its switch point,
  // so judged by it a step that throws out true closures looks downhill (see optimize()).
  double c = graph_.objective(estimate_);
  if (gaugeFactor_ >= 0) c += factors_[gaugeFactor_]->objectiveAt(estimate_);
  return c;
}

bool Isam2Backend::fullSteps(int maxSteps, double relativeTolerance, double& previous,
                             int& iterations, bool* uphill) {
  if (uphill) *uphill = false;
  for (int it = 0; it < maxSteps; ++it) {
    relinearizeAllAtEstimate();
    backSubstitute(nullptr);
    ++iterations;
    const double current = costWithGauge();
    if (!(current <= previous * (1.0 + 1e-9) + 1e-12)) {
      ++epoch_;  // back to θ (the estimate before the last step)
      for (int v = 0; v < theta_.size(); ++v) {
        std::memcpy(estimate_.data(v), theta_.data(v), sizeof(double) * kValueStride);
        std::fill_n(&delta_[static_cast<size_t>(v) * kMaxVarDim], kMaxVarDim, 0.0);
      }
      if (uphill) *uphill = true;
      return false;
    }
    const double gain = previous - current;
    previous = current;
    if (gain <= relativeTolerance * current + 1e-14) return true;
  }
  return false;
}

void Isam2Backend::settle(int maxSteps, double relativeGain) {
  if (factors_.empty() || maxSteps <= 0) return;
  double previous = costWithGauge();
  int iterations = 0;
  fullSteps(maxSteps, relativeGain, previous, iterations);
}

std::vector<char> Isam2Backend::fixedForBatch() const {
  std::vector<char> fixed(static_cast<size_t>(estimate_.size()), 0);
  for (int v = 0; v < estimate_.size(); ++v)
    fixed[static_cast<size_t>(v)] = varFactors_[v].empty() ? 1 : 0;
  return fixed;
}

void Isam2Backend::optimize() {
  if (factors_.empty()) return;
  summary_ = {};
  summary_.initialChi2 = graph_.chi2(estimate_);
  double previous = costWithGauge();
  int iterations = 0;
  bool converged = false, usedBatch = false, uphill = false;
  // BackendOptions::maxIterations (loopd-solve --max-iterations) bounds the whole call: the
  // full steps and the batch fallback's iterations together.
  const int budget = std::max(options_.maxIterations, 1);
  for (int round = 0; round < 2 && !converged; ++round) {
    const int steps = std::min(isam_.maxFinalIterations, budget - iterations);
    converged = fullSteps(steps, isam_.finalRelativeTolerance, previous, iterations, &uphill);
    if (converged || round == 1 || iterations >= budget) break;
    // Gauss–Newton went uphill: Levenberg–Marquardt on the whole graph (on its held
    // majorizer, heldDescent, if any factor re-weights its residual), then rebuild.
    usedBatch = true;
    if (heldDescent(budget, previous, iterations)) continue;
    FactorGraph all = graph_;
    if (gaugeFactor_ >= 0) all.add(factors_[gaugeFactor_]);
    OptimizerOptions o;
    o.method = OptimizerMethod::LevenbergMarquardt;
    o.maxIterations = budget - iterations;
    NonlinearOptimizer lm(all, estimate_, fixedForBatch(), o);
    const OptimizerResult r = lm.optimize(estimate_);
    iterations += r.iterations;
    previous = costWithGauge();
  }
  if (!converged) {
    // Leave the tree linearized at the final estimate without taking another step.
    ++epoch_;
    affected_.clear();
    relinearize(true);
    recompute();
  }
  summary_.iterations = iterations;
  summary_.finalChi2 = graph_.chi2(estimate_);
  summary_.converged = converged;
  summary_.budgetSpent = !converged && iterations >= budget;
  summary_.stopReason = converged ? (usedBatch ? "converged (after batch LM)" : "converged")
                        : uphill  ? (usedBatch ? "Gauss-Newton step uphill (after batch LM)"
                                               : "Gauss-Newton step uphill")
                                  : "iteration limit";
}

}  // namespace loopd
