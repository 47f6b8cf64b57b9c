#pragma once
// Between factor on SE(2), g2o's EDGE_SE2:
//   Δ = Z⁻¹·Xi⁻¹·Xj,   e = (Δx, Δy, wrap(Δθ)) = (Rzᵀ(Riᵀ(tj − ti) − tz), θj − θi − θz)
// With Xi ⊕ δ = Xi·δ (body-frame step):
//   ∂e/∂δi = [−Rzᵀ, Rzᵀ(vy, −vx)ᵀ; 0 0 −1],  v = Riᵀ(tj − ti)
//   ∂e/∂δj = [Rzᵀ Riᵀ Rj, 0; 0 0 1]
#include "solvers/factors/factor.h"

namespace loopd {

class BetweenFactorSE2 final : public Factor {
 public:
  BetweenFactorSE2(Key i, Key j, const SE2& measured, const Eigen::Matrix3d& information,
                   FactorRole role = FactorRole::LoopClosure);

  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "BetweenSE2"; }

  const SE2& measured() const { return measured_; }
  const Eigen::Matrix3d& information() const { return information_; }

 private:
  SE2 measured_;
  Eigen::Matrix3d information_;
  Eigen::Matrix3d sqrtInfo_;
  Mat2 RzT_;
};

}  // namespace loopd
