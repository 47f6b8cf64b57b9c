#pragma once
// Priors on one variable.
//   SE2:    e = (Rzᵀ(t − tz), wrap(θ − θz)),   ∂e/∂δ = [Rzᵀ R, 0; 0 0 1]
//   SE3:    e = Log_SE3(Z⁻¹·X),                ∂e/∂δ = Jr⁻¹(e)
//   PointN: e = p − z,                         ∂e/∂δ = I
#include "solvers/factors/factor.h"

namespace loopd {

class PriorFactorSE2 final : public Factor {
 public:
  PriorFactorSE2(Key k, const SE2& prior, const Eigen::Matrix3d& information);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "PriorSE2"; }
  const SE2& prior() const { return prior_; }

 private:
  SE2 prior_;
  Eigen::Matrix3d sqrtInfo_;
};

class PriorFactorSE3 final : public Factor {
 public:
  PriorFactorSE3(Key k, const SE3& prior, const Mat6& information);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "PriorSE3"; }
  const SE3& prior() const { return prior_; }

 private:
  SE3 prior_;
  SE3 priorInverse_;
  Mat6 sqrtInfo_;
};

template <int N>
class PriorFactorPoint final : public Factor {
 public:
  using VecN = Eigen::Matrix<double, N, 1>;
  using MatN = Eigen::Matrix<double, N, N>;
  PriorFactorPoint(Key k, const VecN& prior, const MatN& information);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return N == 2 ? "PriorPoint2" : "PriorPoint3"; }

 private:
  VecN prior_;
  MatN sqrtInfo_;
};

using PriorFactorPoint2 = PriorFactorPoint<2>;
using PriorFactorPoint3 = PriorFactorPoint<3>;

}  // namespace loopd
