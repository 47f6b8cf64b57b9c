#pragma once
// SE(2) pose (x, y, θ). Retraction: X ⊕ δ = X·(δx, δy, δθ), i.e. the translation step is
// taken in the body frame and θ adds; the residual convention is g2o's (x, y, wrapped θ).
#include <Eigen/Core>
#include <cmath>

namespace loopd {

using Vec2 = Eigen::Vector2d;
using Mat2 = Eigen::Matrix2d;

/// Wraps an angle to (−π, π].
inline double wrapAngle(double a) {
  a = std::fmod(a + M_PI, 2.0 * M_PI);
  if (a <= 0.0) a += 2.0 * M_PI;
  return a - M_PI;
}

inline Mat2 rot2(double theta) {
  const double c = std::cos(theta), s = std::sin(theta);
  Mat2 R;
  R << c, -s, s, c;
  return R;
}

struct SE2 {
  double x = 0.0, y = 0.0, theta = 0.0;

  SE2() = default;
  SE2(double x_, double y_, double theta_) : x(x_), y(y_), theta(theta_) {}

  Vec2 t() const { return {x, y}; }
  Mat2 R() const { return rot2(theta); }

  SE2 operator*(const SE2& o) const {
    const double c = std::cos(theta), s = std::sin(theta);
    return {x + c * o.x - s * o.y, y + s * o.x + c * o.y, wrapAngle(theta + o.theta)};
  }
  SE2 inverse() const {
    const double c = std::cos(theta), s = std::sin(theta);
    return {-c * x - s * y, s * x - c * y, -theta};
  }
  /// this⁻¹·o
  SE2 between(const SE2& o) const { return inverse() * o; }
  Vec2 transform(const Vec2& p) const { return R() * p + t(); }
  Vec2 transformTo(const Vec2& p) const { return R().transpose() * (p - t()); }
  SE2 retract(const Eigen::Vector3d& d) const { return *this * SE2(d.x(), d.y(), d.z()); }
  Eigen::Vector3d vector() const { return {x, y, theta}; }
};

}  // namespace loopd
