#pragma once
// Between factor on SE(3), g2o's EDGE_SE3:QUAT with GTSAM's default residual:
//   Δ = Z⁻¹·Xi⁻¹·Xj,   e = Log_SE3(Δ) = (ρ, φ)  (translation first)
// With right perturbations X·Exp(δ):
//   ∂e/∂δj = Jr⁻¹(e),   ∂e/∂δi = −Jr⁻¹(e)·Ad(Xj⁻¹·Xi)
// exact, so the optimum is the true stationary point of Σ eᵀΩe.
#include "solvers/factors/factor.h"

namespace loopd {

class BetweenFactorSE3 final : public Factor {
 public:
  BetweenFactorSE3(Key i, Key j, const SE3& measured, const Mat6& information,
                   FactorRole role = FactorRole::LoopClosure);

  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "BetweenSE3"; }

  const SE3& measured() const { return measured_; }
  const Mat6& information() const { return information_; }

 private:
  SE3 measured_;
  SE3 measuredInverse_;
  Mat6 information_;
  Mat6 sqrtInfo_;
};

}  // namespace loopd
