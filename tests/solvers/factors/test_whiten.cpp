// Whitening: upperTimes gives the bits of Eigen's triangular product (the factors' residuals
// and Jacobians, and so every stored result, stay what they were before it replaced it) for
// every size the factors use, over square roots and matrices spanning many magnitudes.
// GCC 12 reports a false -Wmaybe-uninitialized inside Eigen's AVX-512 kernels.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <cmath>
#include <cstring>
#include <random>

#include "solvers/factors/whiten.h"

namespace loopd {
namespace {

// Rounds (of 2000) where upperTimes<D, V> and Eigen differ in any bit.
template <int D, int V>
int roundsDiffering(std::mt19937& rng) {
  std::normal_distribution<double> normal;
  auto draw = [&] { return normal(rng) * std::exp(3.0 * normal(rng)); };
  int differing = 0;
  for (int round = 0; round < 2000; ++round) {
    Eigen::Matrix<double, D, D> U = Eigen::Matrix<double, D, D>::Zero();
    for (int i = 0; i < D; ++i)
      for (int k = i; k < D; ++k) U(i, k) = draw();
    Eigen::Matrix<double, D, V> M;
    for (int i = 0; i < D * V; ++i) M.data()[i] = draw();
    Eigen::Matrix<double, D, V> eigen, ours;
    eigen.noalias() = U.template triangularView<Eigen::Upper>() * M;
    detail::upperTimes<D, V>(U, M.data(), ours.data());
    differing += std::memcmp(eigen.data(), ours.data(), sizeof(double) * D * V) != 0;
  }
  return differing;
}

TEST(Whiten, UpperTimesHasTheBitsOfEigensTriangularProduct) {
  std::mt19937 rng(7);
  EXPECT_EQ((roundsDiffering<1, 1>(rng)), 0);
  EXPECT_EQ((roundsDiffering<2, 1>(rng)), 0);
  EXPECT_EQ((roundsDiffering<2, 2>(rng)), 0);
  EXPECT_EQ((roundsDiffering<2, 3>(rng)), 0);
  EXPECT_EQ((roundsDiffering<3, 1>(rng)), 0);
  EXPECT_EQ((roundsDiffering<3, 3>(rng)), 0);
  EXPECT_EQ((roundsDiffering<3, 6>(rng)), 0);
  EXPECT_EQ((roundsDiffering<6, 1>(rng)), 0);
  EXPECT_EQ((roundsDiffering<6, 6>(rng)), 0);
}

TEST(Whiten, WritesOnlyTheJacobiansAskedFor) {
  const Eigen::Matrix2d U = (Eigen::Matrix2d() << 2.0, 1.0, 0.0, 3.0).finished();
  const Eigen::Matrix2d J = (Eigen::Matrix2d() << 1.0, 2.0, 3.0, 4.0).finished();
  double first[4] = {9, 9, 9, 9};
  double* out[2] = {first, nullptr};
  detail::writeJacobian<2, 2>(U, J, out, 0);
  detail::writeJacobian<2, 2>(U, J, out, 1);  // no buffer: nothing written
  detail::writeJacobian<2, 2>(U, J, nullptr, 0);
  // U·J = [[2·1 + 1·3, 2·2 + 1·4], [3·3, 3·4]], column-major.
  EXPECT_EQ(first[0], 5.0);
  EXPECT_EQ(first[1], 9.0);
  EXPECT_EQ(first[2], 8.0);
  EXPECT_EQ(first[3], 12.0);
  double r[2];
  detail::writeResidual<2>(U, Eigen::Vector2d(1.0, 3.0), r);
  EXPECT_EQ(r[0], 5.0);
  EXPECT_EQ(r[1], 9.0);
}

}  // namespace
}  // namespace loopd
