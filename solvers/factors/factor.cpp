#include "solvers/factors/factor.h"

#include <Eigen/Cholesky>
#include <stdexcept>

namespace loopd {

const char* factorRoleName(FactorRole r) {
  switch (r) {
    case FactorRole::Prior:
      return "prior";
    case FactorRole::Odometry:
      return "odometry";
    case FactorRole::LoopClosure:
      return "loop_closure";
    case FactorRole::Landmark:
      return "landmark";
  }
  return "?";
}

Factor::Factor(std::initializer_list<std::pair<Key, VarType>> vars, int dim, FactorRole role)
    : dim_(dim), role_(role) {
  if (vars.size() > static_cast<size_t>(kMaxFactorKeys))
    throw std::invalid_argument("a factor has at most " + std::to_string(kMaxFactorKeys) + " keys");
  for (const auto& [k, t] : vars) {
    keys_[numKeys_] = k;
    varTypes_[numKeys_] = t;
    ++numKeys_;
  }
}

std::array<const double*, kMaxFactorKeys> Factor::storageIn(const Values& values) const {
  std::array<const double*, kMaxFactorKeys> x{};
  for (int i = 0; i < size(); ++i) {
    const int s = values.slot(key(i));
    if (s < 0) throw std::out_of_range("missing variable " + keyToString(key(i)));
    x[i] = values.data(s);
  }
  return x;
}

Eigen::VectorXd Factor::whitenedError(const Values& values) const {
  Eigen::VectorXd r(dim());
  evaluate(storageIn(values).data(), r.data(), nullptr);
  return r;
}

double Factor::chi2(const Values& values) const { return chi2(storageIn(values).data()); }

double Factor::chi2(const double* const* x) const {
  // Aligned like a VectorXd's storage so the sum runs in the same order as
  // whitenedError(values).squaredNorm() did: results stay bit-identical.
  alignas(EIGEN_MAX_ALIGN_BYTES) double r[kMaxResidualDim];
  evaluate(x, r, nullptr);
  return Eigen::Map<const Eigen::VectorXd, Eigen::AlignedMax>(r, dim()).squaredNorm();
}

template <int D>
Eigen::Matrix<double, D, D> sqrtInformation(const Eigen::Matrix<double, D, D>& info) {
  if (!info.allFinite()) throw std::invalid_argument("information matrix is not finite");
  if (!info.isApprox(info.transpose(), 1e-9))
    throw std::invalid_argument("information matrix is not symmetric");
  // Beyond it a residual's χ² overflows (1e300 with a residual of 13), or swamps every other
  // factor's in one sum: the solve goes non-finite and takes the whole graph with it.
  if (info.diagonal().maxCoeff() > kMaxInformation)
    throw std::invalid_argument(
        "information matrix exceeds 1e15 (a standard deviation below 3.2e-8): too tight to "
        "solve in double precision");
  Eigen::LLT<Eigen::Matrix<double, D, D>> llt(info);
  if (llt.info() != Eigen::Success)
    throw std::invalid_argument("information matrix is not positive definite");
  return llt.matrixU();
}

template Eigen::Matrix<double, 1, 1> sqrtInformation<1>(const Eigen::Matrix<double, 1, 1>&);
template Eigen::Matrix<double, 2, 2> sqrtInformation<2>(const Eigen::Matrix<double, 2, 2>&);
template Eigen::Matrix<double, 3, 3> sqrtInformation<3>(const Eigen::Matrix<double, 3, 3>&);
template Eigen::Matrix<double, 6, 6> sqrtInformation<6>(const Eigen::Matrix<double, 6, 6>&);

}  // namespace loopd
