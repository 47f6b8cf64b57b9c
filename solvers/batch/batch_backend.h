#pragma once
// The batch Backend ("gn", "lm", "dogleg"): keeps the whole graph and re-solves it from the
// current estimate after each update. The symbolic factorization is reused until the graph's
// structure changes. Without any prior, the lowest pose is held fixed (the gauge).
#include <functional>
#include <unordered_map>

#include "solvers/backend/backend.h"

namespace loopd {

class BatchBackend : public Backend {
 public:
  explicit BatchBackend(BackendOptions options);

  std::string name() const override;
  UpdateResult update(const BackendUpdate& update) override;
  void optimize() override;
  const Values& estimate() const override { return estimate_; }
  const FactorGraph& graph() const override { return graph_; }
  Eigen::MatrixXd marginalCovariance(const std::vector<Key>& keys) override;
  SolveSummary summary() const override { return summary_; }

  /// Many keys at once, chunked column solves on one factorization.
  std::vector<Eigen::MatrixXd> marginals(const std::vector<Key>& keys) override;
  /// The joint marginal of each key set, all on one factorization (beforeEachSet: as
  /// loopd::jointMarginals).
  std::vector<Eigen::MatrixXd> jointMarginals(const std::vector<std::vector<Key>>& keySets,
                                              const std::function<void()>& beforeEachSet = {});

 protected:
  /// Robust subclasses: per-factor weights for the next solve (nullptr: all ones).
  virtual const double* factorWeights() const { return nullptr; }
  NonlinearOptimizer& optimizer();
  /// Solves with the current weights from the current estimate (kept in lastSolve_).
  OptimizerResult solveOnce();

  BackendOptions options_;
  FactorGraph graph_;
  Values estimate_;
  SolveSummary summary_;
  OptimizerResult lastSolve_;

 private:
  void validate(const BackendUpdate& u) const;
  std::vector<char> gaugeFixedSlots() const;

  std::unordered_map<FactorId, int> factorIndex_;
  std::unique_ptr<NonlinearOptimizer> optimizer_;  // reset when the structure changes
  bool initialized_ = false;
};

}  // namespace loopd
