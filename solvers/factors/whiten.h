#pragma once
// Shared by all factors: write U·e and U·J into the caller's buffers.
#include <Eigen/Core>
#include <cmath>

namespace loopd::detail {

// a·b + c, fused where the machine has FMA: what Eigen's packet kernels do.
inline double multiplyAdd(double a, double b, double c) {
#ifdef __FMA__
  return std::fma(a, b, c);
#else
  return a * b + c;
#endif
}

// out = U·M for the upper-triangular square root U and a column-major D×V matrix M, row i
// summed from its diagonal on: the bits of Eigen's triangular product (test_whiten checks
// them) without its general kernels, whose blocking buffers were zeroed on every call (a
// tenth of an iSAM2 update on manhattan).
template <int D, int V>
inline void upperTimes(const Eigen::Matrix<double, D, D>& U, const double* m, double* out) {
  for (int j = 0; j < V; ++j)
    for (int i = 0; i < D; ++i) {
      double sum = 0.0;
      for (int k = i; k < D; ++k) sum = multiplyAdd(U(i, k), m[j * D + k], sum);
      out[j * D + i] = sum;
    }
}

template <int D>
inline void writeResidual(const Eigen::Matrix<double, D, D>& U,
                          const Eigen::Matrix<double, D, 1>& e, double* r) {
  upperTimes<D, 1>(U, e.data(), r);
}

template <int D, int V>
inline void writeJacobian(const Eigen::Matrix<double, D, D>& U,
                          const Eigen::Matrix<double, D, V>& J, double* const* out, int i) {
  if (out != nullptr && out[i] != nullptr) upperTimes<D, V>(U, J.data(), out[i]);
}

}  // namespace loopd::detail
