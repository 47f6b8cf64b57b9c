#pragma once
// How one uncertain factor is made robust by a reformulation that needs no schedule: a kernel
// (IRLS), a switchable constraint or a max-mixture. Shared by RobustBackend (every uncertain
// factor, one method) and PerFactorRobustBackend (the method a sender asked for per factor).
#include <optional>
#include <string>

#include "robust/robust_factors.h"

namespace loopd {

enum class RobustMethod { Kernel, Switchable, MaxMixture };

struct WrapSpec {
  RobustMethod method = RobustMethod::Kernel;
  KernelType kernel = KernelType::DCS;
  /// Kernel: k (Huber/Cauchy/GM, on ‖r‖) or Φ (DCS); ≤ 0 → default.
  /// Switchable: σ of the switch prior (default 1). MaxMixture: null weight (default 1e-7).
  double parameter = 0.0;
  double switchPrior = 1.0;  // γ
  double nullSigma = 1.6e7;  // max-mixture null hypothesis: Σ₀ = σ₀²·Σ
};

/// The spec of a variant applied per factor: huber, cauchy, gm, dcs, sc, mm; nullopt for any
/// other name (none, the graduated schemes, plain solvers).
std::optional<WrapSpec> wrapSpecFor(const std::string& variant, double parameter);

/// f wrapped per spec (switchKey: the switch variable, Switchable only).
FactorPtr wrapFactor(const FactorPtr& f, const WrapSpec& spec, Key switchKey);

/// The switch variable's prior (Switchable), under id.
FactorPtr switchPrior(Key switchKey, const WrapSpec& spec, FactorId id);

/// Weight in [0, 1] of a wrapper at x: kernel weight, Ψ(switch), 0 if the null component wins.
double wrappedWeight(const Factor& wrapped, const Values& x);

}  // namespace loopd
