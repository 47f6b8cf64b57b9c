#include "solvers/factors/between_factor_se2.h"

#include "solvers/factors/whiten.h"

namespace loopd {

BetweenFactorSE2::BetweenFactorSE2(Key i, Key j, const SE2& measured,
                                   const Eigen::Matrix3d& information, FactorRole role)
    : Factor({{i, VarType::SE2}, {j, VarType::SE2}}, 3, role),
      measured_(measured),
      information_(information),
      sqrtInfo_(sqrtInformation<3>(information)),
      RzT_(measured.R().transpose()) {}

void BetweenFactorSE2::evaluate(const double* const* x, double* r, double* const* J) const {
  const double* a = x[0];
  const double* b = x[1];
  const double ci = std::cos(a[2]), si = std::sin(a[2]);
  const double dx = b[0] - a[0], dy = b[1] - a[1];
  const Vec2 v(ci * dx + si * dy, -si * dx + ci * dy);  // Riᵀ(tj − ti)
  Eigen::Vector3d e;
  e.head<2>() = RzT_ * (v - measured_.t());
  e[2] = wrapAngle(b[2] - a[2] - measured_.theta);
  detail::writeResidual<3>(sqrtInfo_, e, r);
  if (J == nullptr) return;

  Eigen::Matrix3d Ji = Eigen::Matrix3d::Zero();
  Ji.topLeftCorner<2, 2>() = -RzT_;
  Ji.block<2, 1>(0, 2) = RzT_ * Vec2(v.y(), -v.x());
  Ji(2, 2) = -1.0;
  Eigen::Matrix3d Jj = Eigen::Matrix3d::Zero();
  Jj.topLeftCorner<2, 2>() = RzT_ * rot2(b[2] - a[2]);
  Jj(2, 2) = 1.0;
  detail::writeJacobian<3, 3>(sqrtInfo_, Ji, J, 0);
  detail::writeJacobian<3, 3>(sqrtInfo_, Jj, J, 1);
}

std::unique_ptr<Factor> BetweenFactorSE2::clone() const {
  return std::make_unique<BetweenFactorSE2>(*this);
}

}  // namespace loopd
