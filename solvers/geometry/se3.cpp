#include "solvers/geometry/se3.h"

#include <cmath>

namespace loopd {

SE3 SE3::fromTranslationQuaternion(const double* v) {
  Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  q.normalize();
  return {q.toRotationMatrix(), Vec3(v[0], v[1], v[2])};
}

void SE3::toTranslationQuaternion(double* out) const {
  Eigen::Quaterniond q(R);
  q.normalize();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  out[0] = t.x();
  out[1] = t.y();
  out[2] = t.z();
  out[3] = q.x();
  out[4] = q.y();
  out[5] = q.z();
  out[6] = q.w();
}

SE3 SE3::retract(const Vec6& d) const { return {R * expSO3(d.tail<3>()), t + R * d.head<3>()}; }

Mat6 SE3::adjoint() const {
  Mat6 A;
  A.topLeftCorner<3, 3>() = R;
  A.topRightCorner<3, 3>() = hat(t) * R;
  A.bottomLeftCorner<3, 3>().setZero();
  A.bottomRightCorner<3, 3>() = R;
  return A;
}

SE3 expSE3(const Vec6& xi) {
  const Vec3 phi = xi.tail<3>();
  // t = J_l(φ)·ρ, and J_l(φ) = J_r(−φ).
  return {expSO3(phi), rightJacobianSO3(-phi) * xi.head<3>()};
}

Vec6 logSE3(const SE3& X) {
  Vec6 xi;
  const Vec3 phi = logSO3(X.R);
  xi.tail<3>() = phi;
  xi.head<3>() = rightJacobianInverseSO3(-phi) * X.t;
  return xi;
}

namespace {

// Barfoot's Q(ρ, φ), the off-diagonal block of the left Jacobian of SE(3).
Mat3 leftJacobianQ(const Vec3& rho, const Vec3& phi) {
  const Mat3 P = hat(phi), Rh = hat(rho);
  const double t2 = phi.squaredNorm();
  double c1, c2, c3;
  if (t2 < 1e-6) {
    c1 = 1.0 / 6.0 - t2 / 120.0;
    c2 = 1.0 / 24.0 - t2 / 720.0;
    c3 = 1.0 / 120.0 - t2 / 2520.0;
  } else {
    const double t = std::sqrt(t2), s = std::sin(t), c = std::cos(t);
    c1 = (t - s) / (t2 * t);
    c2 = (t2 + 2.0 * c - 2.0) / (2.0 * t2 * t2);
    c3 = (2.0 * t - 3.0 * s + t * c) / (2.0 * t2 * t2 * t);
  }
  const Mat3 PR = P * Rh, RP = Rh * P, PRP = PR * P;
  return 0.5 * Rh + c1 * (PR + RP + PRP) + c2 * (P * PR + RP * P - 3.0 * PRP) +
         c3 * (PRP * P + P * PRP);
}

}  // namespace

Mat6 rightJacobianInverseSE3(const Vec6& xi) {
  // J_r(ξ) = J_l(−ξ) = [[Jr(φ), Q(−ρ, −φ)], [0, Jr(φ)]]; invert the block triangle.
  const Vec3 phi = xi.tail<3>();
  const Mat3 JrInv = rightJacobianInverseSO3(phi);
  const Mat3 Q = leftJacobianQ(-xi.head<3>(), -phi);
  Mat6 J;
  J.topLeftCorner<3, 3>() = JrInv;
  J.topRightCorner<3, 3>() = -JrInv * Q * JrInv;
  J.bottomLeftCorner<3, 3>().setZero();
  J.bottomRightCorner<3, 3>() = JrInv;
  return J;
}

}  // namespace loopd
