#pragma once
// SE(3) pose as (R, t). Tangent order is translation first: ξ = (ρ, φ).
// Retraction X ⊕ (v, ω) = (R·Exp(ω), t + R·v): to first order X·Exp(ξ), cheaper to apply.
#include <Eigen/Core>
#include <Eigen/Geometry>

#include "solvers/geometry/so3.h"

namespace loopd {

using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

struct SE3 {
  Mat3 R = Mat3::Identity();
  Vec3 t = Vec3::Zero();

  SE3() = default;
  SE3(const Mat3& R_, const Vec3& t_) : R(R_), t(t_) {}
  /// From g2o's (x, y, z, qx, qy, qz, qw); the quaternion is normalised.
  static SE3 fromTranslationQuaternion(const double* xyz_qxyzw);
  /// Writes (x, y, z, qx, qy, qz, qw) with qw ≥ 0.
  void toTranslationQuaternion(double* out) const;

  SE3 operator*(const SE3& o) const { return {R * o.R, R * o.t + t}; }
  SE3 inverse() const { return {R.transpose(), -(R.transpose() * t)}; }
  SE3 between(const SE3& o) const { return {R.transpose() * o.R, R.transpose() * (o.t - t)}; }
  Vec3 transform(const Vec3& p) const { return R * p + t; }
  Vec3 transformTo(const Vec3& p) const { return R.transpose() * (p - t); }
  SE3 retract(const Vec6& d) const;
  /// Ad_X, mapping tangent vectors (ρ, φ): Exp(Ad_X ξ) = X·Exp(ξ)·X⁻¹.
  Mat6 adjoint() const;
};

/// Exp of SE(3) for ξ = (ρ, φ).
SE3 expSE3(const Vec6& xi);
/// Log of SE(3): (ρ, φ) with φ = Log(R), ρ = V(φ)⁻¹·t.
Vec6 logSE3(const SE3& X);
/// Inverse right Jacobian of SE(3) Exp at ξ: Log(Exp(ξ)·Exp(δ)) ≈ ξ + Jr⁻¹(ξ)·δ.
Mat6 rightJacobianInverseSE3(const Vec6& xi);

}  // namespace loopd
