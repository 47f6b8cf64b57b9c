#pragma once
// HeldKernelFactor: an M-estimator kernel whose IRLS weight is held fixed between refreshes,
// for solvers that judge each step by the cost they evaluate (batch LM, GN, Dogleg).
//
// KernelFactor re-evaluates its weight at every point, so such a solver compares
// Σ w(χ²(x))·χ²(x) between steps. For a redescending kernel (DCS, Geman–McClure) that
// product peaks at χ² ≈ Φ and falls towards 0 beyond: a closure far from agreement "costs"
// less the further it is pulled apart, so every step that would bring it in is refused.
// Held, the weight makes each solve a true weighted least-squares problem; refreshing it at
// the solution (w = ρ'(χ²)) is IRLS as majorization–minimization: every kernel here has ρ
// concave in χ², so w·χ² + const bounds ρ from above, touching it at the refresh point, and
// each solve lowers Σρ.
#include <memory>

#include "robust/robust_factors.h"

namespace loopd {

class HeldKernelFactor final : public Factor {
 public:
  /// parameter ≤ 0: defaultKernelParameter(kernel, inner->dim()). Starts at weight 1.
  static std::shared_ptr<HeldKernelFactor> make(FactorPtr inner, KernelType kernel,
                                                double parameter = 0.0);
  template <size_t... I>
  HeldKernelFactor(std::index_sequence<I...>, FactorPtr inner, KernelType kernel, double parameter);

  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "HeldKernel"; }

  const FactorPtr& inner() const { return inner_; }
  double heldWeight() const { return weight_; }
  /// The kernel's weight at values (inner χ² there), whatever is held.
  double weightAt(const Values& values) const;
  /// Holds the kernel's weight at values; returns |new − old|. Only between solves: the
  /// solver reads the weight while it runs.
  double holdWeightAt(const Values& values);

 private:
  FactorPtr inner_;
  KernelType kernel_;
  double parameter_;
  double weight_ = 1.0;
};

}  // namespace loopd
