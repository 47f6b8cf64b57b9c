#pragma once
// A nonlinear factor graph: the factors, in insertion order.
#include <vector>

#include "solvers/factors/factor.h"

namespace loopd {

class FactorGraph {
 public:
  void add(FactorPtr f) { factors_.push_back(std::move(f)); }
  void reserve(size_t n) { factors_.reserve(n); }
  int size() const { return static_cast<int>(factors_.size()); }
  bool empty() const { return factors_.empty(); }
  const FactorPtr& operator[](int i) const { return factors_[i]; }
  const std::vector<FactorPtr>& factors() const { return factors_; }
  std::vector<FactorPtr>& factors() { return factors_; }

  /// Σ rᵀr over all factors (g2o's chi2). Throws if a key is missing from values.
  double chi2(const Values& values) const;
  /// Σ Factor::objective over all factors: what a solver minimises (chi2 unless robust
  /// wrappers re-weight their residuals).
  double objective(const Values& values) const;

 private:
  std::vector<FactorPtr> factors_;
};

}  // namespace loopd
