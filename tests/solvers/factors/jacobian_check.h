#pragma once
// Factor Jacobians against numerical differentiation, and random information matrices: what
// the factor tests share.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <array>
#include <limits>
#include <random>
#include <string>

#include "solvers/core/values.h"
#include "solvers/factors/factor.h"

namespace loopd::test {

/// A random information matrix for the checks.
template <int N>
inline Eigen::Matrix<double, N, N> randomInformation(std::mt19937& rng) {
  // Ω = L·Lᵀ with a random lower-triangular L and diagonal in [0.5, 4]: SPD, dense, and
  // with a spread of scales.
  std::uniform_real_distribution<double> off(-1.0, 1.0), diag(0.5, 4.0);
  Eigen::Matrix<double, N, N> L = Eigen::Matrix<double, N, N>::Zero();
  for (int r = 0; r < N; ++r) {
    for (int c = 0; c < r; ++c) L(r, c) = off(rng);
    L(r, r) = diag(rng);
  }
  return L * L.transpose();
}

/// Analytic Jacobians against central differences of the whitened residual, perturbing each
/// slot through Values::retract by ±h·e_k; a null entry in J must skip that key only. With
/// `everyKeyMatters`, each block must also depend on its variable at these values (so a block
/// left out cannot pass as zero).
inline void checkJacobians(const Factor& f, const Values& values, const std::string& label,
                           double h = 1e-6, double relTol = 1e-6, bool everyKeyMatters = false) {
  SCOPED_TRACE(label);
  const int d = f.dim();
  std::array<const double*, kMaxFactorKeys> x{};
  for (int i = 0; i < f.size(); ++i) {
    const int s = values.slot(f.key(i));
    ASSERT_GE(s, 0);
    ASSERT_EQ(values.type(s), f.varType(i));
    x[i] = values.data(s);
  }
  std::array<JacobianBlock, kMaxFactorKeys> jac;
  for (auto& b : jac) b.fill(std::numeric_limits<double>::quiet_NaN());
  double* J[kMaxFactorKeys];
  for (int i = 0; i < kMaxFactorKeys; ++i) J[i] = jac[i].data();
  double r[kMaxResidualDim];
  f.evaluate(x.data(), r, J);
  const Eigen::VectorXd r0 = f.whitenedError(values);
  ASSERT_EQ(r0.size(), d);
  for (int i = 0; i < d; ++i) EXPECT_EQ(r[i], r0[i]) << "residual with and without J differ";

  for (int i = 0; i < f.size(); ++i) {
    const int s = values.slot(f.key(i));
    const int n = varDim(values.type(s));
    const Eigen::MatrixXd Ja = Eigen::Map<const Eigen::MatrixXd>(J[i], d, n);
    ASSERT_TRUE(Ja.allFinite()) << "key " << i << " Jacobian not fully written\n" << Ja;
    Eigen::MatrixXd Jn(d, n);
    for (int k = 0; k < n; ++k) {
      Values vp = values, vm = values;
      std::array<double, kMaxVarDim> delta{};
      delta[k] = h;
      vp.retract(s, delta.data());
      delta[k] = -h;
      vm.retract(s, delta.data());
      Jn.col(k) = (f.whitenedError(vp) - f.whitenedError(vm)) / (2.0 * h);
    }
    EXPECT_LT((Ja - Jn).norm(), relTol * (1.0 + Jn.norm()))
        << "key " << i << " (" << keyToString(f.key(i)) << ")\nanalytic\n"
        << Ja << "\nnumerical\n"
        << Jn;
    if (everyKeyMatters) EXPECT_GT(Jn.norm(), 1e-3) << "key " << i;
  }

  // A null entry in J skips that key only; the others are unchanged.
  for (int skip = 0; skip < f.size(); ++skip) {
    std::array<JacobianBlock, kMaxFactorKeys> jac2;
    for (auto& b : jac2) b.fill(-7.0);
    double* J2[kMaxFactorKeys];
    for (int i = 0; i < kMaxFactorKeys; ++i) J2[i] = jac2[i].data();
    J2[skip] = nullptr;
    double r2[kMaxResidualDim];
    f.evaluate(x.data(), r2, J2);
    for (int i = 0; i < d; ++i) EXPECT_EQ(r2[i], r[i]);
    for (int i = 0; i < f.size(); ++i) {
      if (i == skip) continue;
      const int n = varDim(f.varType(i));
      for (int c = 0; c < d * n; ++c) EXPECT_EQ(jac2[i][c], jac[i][c]);
    }
  }
}

}  // namespace loopd::test
