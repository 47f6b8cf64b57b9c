#pragma once
// DecoratorBackend: the common part of the Backend decorators that wrap uncertain factors
// before an inner backend sees them (RobustBackend, RisamBackend). It owns the inner backend
// and the ORIGINAL (unwrapped) factors, forwards what does not depend on the wrapping, and
// returns the originals from graph(), so chi2() is Σ rᵀr of the input, unweighted.
#include <memory>
#include <stdexcept>
#include <string>
#include <unordered_set>
#include <utility>

#include "solvers/backend/backend.h"

namespace loopd {

class DecoratorBackend : public Backend {
 public:
  void optimize() override { inner_->optimize(); }
  const Values& estimate() const override { return inner_->estimate(); }
  const FactorGraph& graph() const override { return originals_; }
  Eigen::MatrixXd marginalCovariance(const std::vector<Key>& keys) override {
    return inner_->marginalCovariance(keys);
  }
  std::vector<Eigen::MatrixXd> marginals(const std::vector<Key>& keys) override {
    return inner_->marginals(keys);
  }
  SolveSummary summary() const override { return inner_->summary(); }
  /// The backend the wrapped factors go to (for what only it can say: which marginals the
  /// data determine).
  const Backend& inner() const { return *inner_; }

 protected:
  /// Throws std::invalid_argument("WHO: null inner backend") if inner is null.
  DecoratorBackend(std::unique_ptr<Backend> inner, const char* who) : inner_(std::move(inner)) {
    if (!inner_) throw std::invalid_argument(std::string(who) + ": null inner backend");
  }

  /// Once the inner backend accepted update u: drops the originals whose ids are in removing
  /// (u's removals) and adds u's factors.
  void commitOriginals(const BackendUpdate& u, const std::unordered_set<FactorId>& removing) {
    if (!removing.empty()) {
      FactorGraph kept;
      for (const auto& f : originals_.factors())
        if (!removing.count(f->id())) kept.add(f);
      originals_ = std::move(kept);
    }
    for (const auto& f : u.factors) originals_.add(f);
  }

  std::unique_ptr<Backend> inner_;
  FactorGraph originals_;
};

}  // namespace loopd
