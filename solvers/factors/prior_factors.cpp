#include "solvers/factors/prior_factors.h"

#include "solvers/factors/whiten.h"

namespace loopd {

PriorFactorSE2::PriorFactorSE2(Key k, const SE2& prior, const Eigen::Matrix3d& information)
    : Factor({{k, VarType::SE2}}, 3, FactorRole::Prior),
      prior_(prior),
      sqrtInfo_(sqrtInformation<3>(information)) {}

void PriorFactorSE2::evaluate(const double* const* x, double* r, double* const* J) const {
  const double* a = x[0];
  const Mat2 RzT = prior_.R().transpose();
  Eigen::Vector3d e;
  e.head<2>() = RzT * (Vec2(a[0], a[1]) - prior_.t());
  e[2] = wrapAngle(a[2] - prior_.theta);
  detail::writeResidual<3>(sqrtInfo_, e, r);
  if (J == nullptr) return;
  Eigen::Matrix3d Jx = Eigen::Matrix3d::Zero();
  Jx.topLeftCorner<2, 2>() = RzT * rot2(a[2]);
  Jx(2, 2) = 1.0;
  detail::writeJacobian<3, 3>(sqrtInfo_, Jx, J, 0);
}

std::unique_ptr<Factor> PriorFactorSE2::clone() const {
  return std::make_unique<PriorFactorSE2>(*this);
}

PriorFactorSE3::PriorFactorSE3(Key k, const SE3& prior, const Mat6& information)
    : Factor({{k, VarType::SE3}}, 6, FactorRole::Prior),
      prior_(prior),
      priorInverse_(prior.inverse()),
      sqrtInfo_(sqrtInformation<6>(information)) {}

void PriorFactorSE3::evaluate(const double* const* x, double* r, double* const* J) const {
  const SE3 X(Eigen::Map<const Mat3>(x[0]), Eigen::Map<const Vec3>(x[0] + 9));
  const Vec6 e = logSE3(priorInverse_ * X);
  detail::writeResidual<6>(sqrtInfo_, e, r);
  if (J == nullptr) return;
  detail::writeJacobian<6, 6>(sqrtInfo_, rightJacobianInverseSE3(e), J, 0);
}

std::unique_ptr<Factor> PriorFactorSE3::clone() const {
  return std::make_unique<PriorFactorSE3>(*this);
}

template <int N>
PriorFactorPoint<N>::PriorFactorPoint(Key k, const VecN& prior, const MatN& information)
    : Factor({{k, N == 2 ? VarType::Point2 : VarType::Point3}}, N, FactorRole::Prior),
      prior_(prior),
      sqrtInfo_(sqrtInformation<N>(information)) {}

template <int N>
void PriorFactorPoint<N>::evaluate(const double* const* x, double* r, double* const* J) const {
  const VecN e = Eigen::Map<const VecN>(x[0]) - prior_;
  detail::writeResidual<N>(sqrtInfo_, e, r);
  if (J == nullptr) return;
  detail::writeJacobian<N, N>(sqrtInfo_, MatN::Identity(), J, 0);
}

template <int N>
std::unique_ptr<Factor> PriorFactorPoint<N>::clone() const {
  return std::make_unique<PriorFactorPoint<N>>(*this);
}

template class PriorFactorPoint<2>;
template class PriorFactorPoint<3>;

}  // namespace loopd
