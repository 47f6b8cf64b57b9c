#pragma once
// Inter-robot between factors through anchors (Kim et al., ICRA 2010): robot r's poses live
// in r's own frame and its anchor A_r places that frame in the common one. A measurement Z of
// x_s seen from x_r (robots r ≠ s) is evaluated on the common-frame poses
//   P = A_r·x_r,  Q = A_s·x_s,  e = between(P, Q) residual of Z (BetweenFactorSE2/SE3's).
// Keys, in order: A_r, x_r, A_s, x_s. With right perturbations, A·Exp(δ)·x = A·x·Exp(Ad(x⁻¹)δ),
// so ∂e/∂δA_r = ∂e/∂δP·Ad(x_r⁻¹), ∂e/∂δx_r = ∂e/∂δP (and the same for s).
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"

namespace loopd {

class AnchoredBetweenFactorSE2 final : public Factor {
 public:
  AnchoredBetweenFactorSE2(Key anchorR, Key poseR, Key anchorS, Key poseS, const SE2& measured,
                           const Eigen::Matrix3d& information,
                           FactorRole role = FactorRole::LoopClosure);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "AnchoredBetweenSE2"; }
  const SE2& measured() const { return inner_.measured(); }
  const Eigen::Matrix3d& information() const { return inner_.information(); }

 private:
  BetweenFactorSE2 inner_;  // evaluated on (P, Q)
};

class AnchoredBetweenFactorSE3 final : public Factor {
 public:
  AnchoredBetweenFactorSE3(Key anchorR, Key poseR, Key anchorS, Key poseS, const SE3& measured,
                           const Mat6& information, FactorRole role = FactorRole::LoopClosure);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "AnchoredBetweenSE3"; }
  const SE3& measured() const { return inner_.measured(); }
  const Mat6& information() const { return inner_.information(); }

 private:
  BetweenFactorSE3 inner_;
};

/// Ad of an SE(2) pose on tangent vectors (δx, δy, δθ).
Eigen::Matrix3d adjointSE2(const SE2& X);

}  // namespace loopd
