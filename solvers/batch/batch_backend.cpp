#include "solvers/batch/batch_backend.h"

#include <chrono>
#include <stdexcept>

#include "solvers/backend/moved_keys.h"
#include "solvers/backend/update_validation.h"
#include "solvers/init/initialization.h"
#include "solvers/marginals/batch_marginals.h"

namespace loopd {

BatchBackend::BatchBackend(BackendOptions options) : options_(std::move(options)) {}

std::string BatchBackend::name() const { return optimizerMethodName(options_.method); }

void BatchBackend::validate(const BackendUpdate& u) const {
  validateUpdate(u, estimate_, factorIndex_, u.initial);
}

UpdateResult BatchBackend::update(const BackendUpdate& u) {
  const auto t0 = std::chrono::steady_clock::now();
  validate(u);
  const Values before = estimate_;
  if (!u.removals.empty()) {
    std::unordered_map<FactorId, int> removing;
    for (FactorId id : u.removals) removing.emplace(id, 0);
    FactorGraph kept;
    for (const auto& f : graph_.factors())
      if (!removing.count(f->id())) kept.add(f);
    graph_ = std::move(kept);
  }
  for (int s = 0; s < u.initial.size(); ++s) estimate_.insertFrom(u.initial, s);
  for (const auto& f : u.factors) graph_.add(f);
  factorIndex_.clear();
  for (int i = 0; i < graph_.size(); ++i) factorIndex_[graph_[i]->id()] = i;
  optimizer_.reset();
  optimize();

  UpdateResult result;
  result.moved = movedKeys(before, estimate_, options_.moveThreshold);
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

std::vector<char> BatchBackend::gaugeFixedSlots() const {
  for (const auto& f : graph_.factors())
    if (f->role() == FactorRole::Prior) return {};
  std::vector<char> fixed(estimate_.size(), 0);
  int lowest = -1;
  for (int s = 0; s < estimate_.size(); ++s)
    if (keyKind(estimate_.key(s)) == KeyKind::Pose &&
        (lowest < 0 || estimate_.key(s) < estimate_.key(lowest)))
      lowest = s;
  if (lowest >= 0) fixed[lowest] = 1;
  return fixed;
}

NonlinearOptimizer& BatchBackend::optimizer() {
  if (!optimizer_) {
    OptimizerOptions o;
    o.method = options_.method;
    o.maxIterations = options_.maxIterations;
    o.progress = options_.progress;
    optimizer_ = std::make_unique<NonlinearOptimizer>(graph_, estimate_, gaugeFixedSlots(), o);
  }
  return *optimizer_;
}

OptimizerResult BatchBackend::solveOnce() {
  lastSolve_ = optimizer().optimize(estimate_, factorWeights());
  return lastSolve_;
}

void BatchBackend::optimize() {
  if (graph_.empty()) return;
  if (!initialized_ && options_.linearInitialization) {
    const std::vector<char> fixed = gaugeFixedSlots();
    Key anchor = 0;
    bool found = false;
    for (int s = 0; s < estimate_.size() && !found; ++s)
      if (!fixed.empty() && fixed[s]) anchor = estimate_.key(s), found = true;
    for (int s = 0; s < estimate_.size() && !found; ++s)
      if (keyKind(estimate_.key(s)) == KeyKind::Pose) anchor = estimate_.key(s), found = true;
    if (found) estimate_ = initializeLinear(graph_, estimate_, anchor);
  }
  initialized_ = true;
  const OptimizerResult r = solveOnce();
  summary_.iterations = r.iterations;
  summary_.initialChi2 = r.initialChi2;
  summary_.finalChi2 = r.finalChi2;
  summary_.converged = r.converged;
  summary_.budgetSpent = r.budgetSpent;
  summary_.stopReason = r.stopReason;
}

Eigen::MatrixXd BatchBackend::marginalCovariance(const std::vector<Key>& keys) {
  return jointMarginal(optimizer(), estimate_, keys, factorWeights());
}

std::vector<Eigen::MatrixXd> BatchBackend::jointMarginals(
    const std::vector<std::vector<Key>>& keySets, const std::function<void()>& beforeEachSet) {
  return loopd::jointMarginals(optimizer(), estimate_, keySets, factorWeights(), beforeEachSet);
}

std::vector<Eigen::MatrixXd> BatchBackend::marginals(const std::vector<Key>& keys) {
  return individualMarginals(optimizer(), estimate_, keys, factorWeights());
}

}  // namespace loopd
