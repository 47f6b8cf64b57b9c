#pragma once
// Shared by all factors: write U·e and U·J into the caller's buffers.
#include <Eigen/Core>

namespace loopd::detail {

template <int D>
inline void writeResidual(const Eigen::Matrix<double, D, D>& U,
                          const Eigen::Matrix<double, D, 1>& e, double* r) {
  Eigen::Map<Eigen::Matrix<double, D, 1>>(r).noalias() =
      U.template triangularView<Eigen::Upper>() * e;
}

template <int D, int V>
inline void writeJacobian(const Eigen::Matrix<double, D, D>& U,
                          const Eigen::Matrix<double, D, V>& J, double* const* out, int i) {
  if (out != nullptr && out[i] != nullptr)
    Eigen::Map<Eigen::Matrix<double, D, V>>(out[i]).noalias() =
        U.template triangularView<Eigen::Upper>() * J;
}

}  // namespace loopd::detail
