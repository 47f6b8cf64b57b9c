#pragma once
// The geometry and factor tests' reference forms: poses as homogeneous matrices (what the
// closed-form operations are checked against) and random unit axes.
#include <Eigen/Core>
#include <random>

#include "solvers/geometry/se2.h"
#include "solvers/geometry/se3.h"

namespace loopd::test {

inline Eigen::Matrix4d homogeneous(const SE3& X) {
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() = X.R;
  T.topRightCorner<3, 1>() = X.t;
  return T;
}

inline Eigen::Matrix3d homogeneous(const SE2& X) {
  Eigen::Matrix3d T = Eigen::Matrix3d::Identity();
  T.topLeftCorner<2, 2>() = rot2(X.theta);
  T(0, 2) = X.x;
  T(1, 2) = X.y;
  return T;
}

inline Vec3 randomUnit(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  return Vec3(n(rng), n(rng), n(rng)).normalized();
}

}  // namespace loopd::test
