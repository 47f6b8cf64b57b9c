#include "solvers/factors/between_factor_se3.h"

#include "solvers/factors/whiten.h"

namespace loopd {

BetweenFactorSE3::BetweenFactorSE3(Key i, Key j, const SE3& measured, const Mat6& information,
                                   FactorRole role)
    : Factor({{i, VarType::SE3}, {j, VarType::SE3}}, 6, role),
      measured_(measured),
      measuredInverse_(measured.inverse()),
      information_(information),
      sqrtInfo_(sqrtInformation<6>(information)) {}

void BetweenFactorSE3::evaluate(const double* const* x, double* r, double* const* J) const {
  const Eigen::Map<const Mat3> Ri(x[0]), Rj(x[1]);
  const Eigen::Map<const Vec3> ti(x[0] + 9), tj(x[1] + 9);
  // Xi⁻¹·Xj, then Z⁻¹ on the left.
  const Mat3 RiT = Ri.transpose();
  const SE3 ij(RiT * Rj, RiT * (tj - ti));
  const SE3 delta = measuredInverse_ * ij;
  const Vec6 e = logSE3(delta);
  detail::writeResidual<6>(sqrtInfo_, e, r);
  if (J == nullptr) return;

  const Mat6 JrInv = rightJacobianInverseSE3(e);
  // Ad(Xj⁻¹·Xi) = Ad((Xi⁻¹·Xj)⁻¹)
  const Mat6 Ji = -JrInv * ij.inverse().adjoint();
  detail::writeJacobian<6, 6>(sqrtInfo_, Ji, J, 0);
  detail::writeJacobian<6, 6>(sqrtInfo_, JrInv, J, 1);
}

std::unique_ptr<Factor> BetweenFactorSE3::clone() const {
  return std::make_unique<BetweenFactorSE3>(*this);
}

}  // namespace loopd
