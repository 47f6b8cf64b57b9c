#include "solvers/geometry/so3.h"

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <cmath>

namespace loopd {

Mat3 hat(const Vec3& w) {
  Mat3 W;
  W << 0.0, -w.z(), w.y(), w.z(), 0.0, -w.x(), -w.y(), w.x(), 0.0;
  return W;
}

Mat3 expSO3(const Vec3& w) {
  const double t2 = w.squaredNorm();
  const Mat3 W = hat(w);
  double a, b;  // sinθ/θ, (1−cosθ)/θ²
  if (t2 < 1e-10) {
    a = 1.0 - t2 / 6.0;
    b = 0.5 - t2 / 24.0;
  } else {
    const double t = std::sqrt(t2);
    a = std::sin(t) / t;
    b = (1.0 - std::cos(t)) / t2;
  }
  return Mat3::Identity() + a * W + b * W * W;
}

Vec3 logSO3(const Mat3& R) {
  // Through the quaternion: θ = 2·atan2(|v|, w) is well conditioned over [0, π].
  Eigen::Quaterniond q(R);
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  const Vec3 v = q.vec();
  const double vn = v.norm();
  if (vn < 1e-12) return 2.0 * v / q.w();  // θ ≈ 2|v| for tiny angles
  const double theta = 2.0 * std::atan2(vn, q.w());
  return (theta / vn) * v;
}

Mat3 rightJacobianSO3(const Vec3& w) {
  const double t2 = w.squaredNorm();
  const Mat3 W = hat(w);
  double a, b;  // (1−cosθ)/θ², (θ−sinθ)/θ³
  if (t2 < 1e-10) {
    a = 0.5 - t2 / 24.0;
    b = 1.0 / 6.0 - t2 / 120.0;
  } else {
    const double t = std::sqrt(t2);
    a = (1.0 - std::cos(t)) / t2;
    b = (t - std::sin(t)) / (t2 * t);
  }
  return Mat3::Identity() - a * W + b * W * W;
}

Mat3 rightJacobianInverseSO3(const Vec3& w) {
  const double t2 = w.squaredNorm();
  const Mat3 W = hat(w);
  double c;  // 1/θ² − cot(θ/2)/(2θ): the (1+cosθ)/sinθ form is 0/0 at θ = π
  if (t2 < 1e-8) {
    c = 1.0 / 12.0 + t2 / 720.0;
  } else {
    const double t = std::sqrt(t2);
    c = 1.0 / t2 - 0.5 / (t * std::tan(0.5 * t));
  }
  return Mat3::Identity() + 0.5 * W + c * W * W;
}

Mat3 projectToSO3(const Mat3& M) {
  Eigen::JacobiSVD<Mat3> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 D = Mat3::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0 ? -1.0 : 1.0;
  return svd.matrixU() * D * svd.matrixV().transpose();
}

}  // namespace loopd
