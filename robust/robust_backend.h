#pragma once
// RobustBackend: a Backend decorator that makes any inner Backend (batch "lm", incremental
// "isam2", …) robust by wrapping each incoming uncertain factor (role LoopClosure/Landmark)
// in a robust factor; trusted factors (priors, odometry) pass through unchanged.
//
//   Kernel:      KernelFactor (Huber, Cauchy, Geman–McClure, DCS) — IRLS.
//   Switchable:  SwitchableFactor + a switch variable s (Scalar, KeyKind::Switch, initial 1)
//                + SwitchPriorFactor(γ = 1, σ = robustParameter or 1).
//   MaxMixture:  MaxMixtureFactor (null weight 1e-7, null σ 1.6e7 relative to the inlier).
//
// The inner backend sees the wrapped factors under the same ids; switch priors get ids with
// the top bit set (original ids must stay below 2⁶³). graph() returns the ORIGINAL factors, so
// chi2() is Σ rᵀr of the input, unweighted. decisions()/rejected() are in original ids.
#include <memory>
#include <unordered_map>

#include "robust/decorator_backend.h"
#include "robust/robust_wrapping.h"

namespace loopd {

struct RobustBackendOptions : WrapSpec {
  double rejectBelow = 0.5;  // weight < this → rejected
};

class RobustBackend : public DecoratorBackend {
 public:
  RobustBackend(std::string name, std::unique_ptr<Backend> inner, RobustBackendOptions options);

  std::string name() const override { return name_; }
  UpdateResult update(const BackendUpdate& update) override;
  std::vector<std::pair<FactorId, double>> decisions() const override;
  std::vector<FactorId> rejected() const override;
  bool judgesUncertain() const override { return true; }

  const Backend& inner() const { return *inner_; }
  /// The switch variable of an original factor (Switchable only), or 0.
  Key switchOf(FactorId id) const;

  static constexpr FactorId kInternalIdBit = FactorId{1} << 63;

 private:
  std::string name_;
  RobustBackendOptions options_;
  std::unordered_map<FactorId, FactorPtr> wrapped_;  // original id → wrapper (uncertain only)
  std::unordered_map<FactorId, Key> switches_;       // original id → switch key
  std::uint64_t nextSwitch_ = 0;
};

}  // namespace loopd
