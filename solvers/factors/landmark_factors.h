#pragma once
// Pose–landmark factors: a landmark observed from a pose.
//   PosePoint2/3: e = Rᵀ(p − t) − z  (landmark position in the pose frame)
//     ∂e/∂δpose = [−I, (vy, −vx)ᵀ] in 2D, [−I, [v]×] in 3D,  v = Rᵀ(p − t);  ∂e/∂p = Rᵀ
//   BearingRange2: v as above, e = (wrap(atan2(vy, vx) − zb), |v| − zr)
//     ∂b/∂v = (−vy, vx)/|v|²,  ∂ρ/∂v = vᵀ/|v|, chained through ∂v/∂δpose and ∂v/∂p.
#include "solvers/factors/factor.h"

namespace loopd {

class PosePointFactor2 final : public Factor {
 public:
  PosePointFactor2(Key pose, Key point, const Vec2& measured, const Eigen::Matrix2d& information,
                   FactorRole role = FactorRole::Landmark);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "PosePoint2"; }
  const Vec2& measured() const { return measured_; }
  const Eigen::Matrix2d& information() const { return information_; }

 private:
  Vec2 measured_;
  Eigen::Matrix2d information_;
  Eigen::Matrix2d sqrtInfo_;
};

class PosePointFactor3 final : public Factor {
 public:
  PosePointFactor3(Key pose, Key point, const Vec3& measured, const Mat3& information,
                   FactorRole role = FactorRole::Landmark);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "PosePoint3"; }
  const Vec3& measured() const { return measured_; }
  const Mat3& information() const { return information_; }

 private:
  Vec3 measured_;
  Mat3 information_;
  Mat3 sqrtInfo_;
};

class BearingRangeFactor2 final : public Factor {
 public:
  /// measured = (bearing rad, range m); information over (bearing, range).
  BearingRangeFactor2(Key pose, Key point, const Vec2& measured, const Eigen::Matrix2d& information,
                      FactorRole role = FactorRole::Landmark);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "BearingRange2"; }
  const Vec2& measured() const { return measured_; }
  const Eigen::Matrix2d& information() const { return information_; }

 private:
  Vec2 measured_;
  Eigen::Matrix2d information_;
  Eigen::Matrix2d sqrtInfo_;
};

}  // namespace loopd
