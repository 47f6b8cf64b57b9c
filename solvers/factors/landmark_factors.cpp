#include "solvers/factors/landmark_factors.h"

#include "solvers/factors/whiten.h"

namespace loopd {

PosePointFactor2::PosePointFactor2(Key pose, Key point, const Vec2& measured,
                                   const Eigen::Matrix2d& information, FactorRole role)
    : Factor({{pose, VarType::SE2}, {point, VarType::Point2}}, 2, role),
      measured_(measured),
      information_(information),
      sqrtInfo_(sqrtInformation<2>(information)) {}

void PosePointFactor2::evaluate(const double* const* x, double* r, double* const* J) const {
  const double* a = x[0];
  const Mat2 RT = rot2(a[2]).transpose();
  const Vec2 v = RT * (Eigen::Map<const Vec2>(x[1]) - Vec2(a[0], a[1]));
  detail::writeResidual<2>(sqrtInfo_, Vec2(v - measured_), r);
  if (J == nullptr) return;
  Eigen::Matrix<double, 2, 3> Jp;
  Jp << -1.0, 0.0, v.y(), 0.0, -1.0, -v.x();
  detail::writeJacobian<2, 3>(sqrtInfo_, Jp, J, 0);
  detail::writeJacobian<2, 2>(sqrtInfo_, RT, J, 1);
}

std::unique_ptr<Factor> PosePointFactor2::clone() const {
  return std::make_unique<PosePointFactor2>(*this);
}

PosePointFactor3::PosePointFactor3(Key pose, Key point, const Vec3& measured,
                                   const Mat3& information, FactorRole role)
    : Factor({{pose, VarType::SE3}, {point, VarType::Point3}}, 3, role),
      measured_(measured),
      information_(information),
      sqrtInfo_(sqrtInformation<3>(information)) {}

void PosePointFactor3::evaluate(const double* const* x, double* r, double* const* J) const {
  const Eigen::Map<const Mat3> R(x[0]);
  const Eigen::Map<const Vec3> t(x[0] + 9);
  const Mat3 RT = R.transpose();
  const Vec3 v = RT * (Eigen::Map<const Vec3>(x[1]) - t);
  detail::writeResidual<3>(sqrtInfo_, Vec3(v - measured_), r);
  if (J == nullptr) return;
  Eigen::Matrix<double, 3, 6> Jp;
  Jp.leftCols<3>() = -Mat3::Identity();
  Jp.rightCols<3>() = hat(v);
  detail::writeJacobian<3, 6>(sqrtInfo_, Jp, J, 0);
  detail::writeJacobian<3, 3>(sqrtInfo_, RT, J, 1);
}

std::unique_ptr<Factor> PosePointFactor3::clone() const {
  return std::make_unique<PosePointFactor3>(*this);
}

BearingRangeFactor2::BearingRangeFactor2(Key pose, Key point, const Vec2& measured,
                                         const Eigen::Matrix2d& information, FactorRole role)
    : Factor({{pose, VarType::SE2}, {point, VarType::Point2}}, 2, role),
      measured_(measured),
      information_(information),
      sqrtInfo_(sqrtInformation<2>(information)) {}

void BearingRangeFactor2::evaluate(const double* const* x, double* r, double* const* J) const {
  const double* a = x[0];
  const Mat2 RT = rot2(a[2]).transpose();
  const Vec2 v = RT * (Eigen::Map<const Vec2>(x[1]) - Vec2(a[0], a[1]));
  const double range2 = std::max(v.squaredNorm(), 1e-18);  // a landmark on the pose: no NaN
  const double range = std::sqrt(range2);
  const Vec2 e(wrapAngle(std::atan2(v.y(), v.x()) - measured_[0]), range - measured_[1]);
  detail::writeResidual<2>(sqrtInfo_, e, r);
  if (J == nullptr) return;
  Mat2 dv;  // ∂(b, ρ)/∂v
  dv << -v.y() / range2, v.x() / range2, v.x() / range, v.y() / range;
  Eigen::Matrix<double, 2, 3> dvPose;
  dvPose << -1.0, 0.0, v.y(), 0.0, -1.0, -v.x();
  const Eigen::Matrix<double, 2, 3> Jp = dv * dvPose;
  const Mat2 Jl = dv * RT;
  detail::writeJacobian<2, 3>(sqrtInfo_, Jp, J, 0);
  detail::writeJacobian<2, 2>(sqrtInfo_, Jl, J, 1);
}

std::unique_ptr<Factor> BearingRangeFactor2::clone() const {
  return std::make_unique<BearingRangeFactor2>(*this);
}

}  // namespace loopd
