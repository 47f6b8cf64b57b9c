#include "solvers/linear/hessian_factorization.h"

#include <Eigen/Core>

namespace loopd {

HessianFactorization::HessianFactorization(FactorizationKind kind) : kind_(kind) {
  if (kind_ != FactorizationKind::Block) cholmod_ = std::make_unique<SparseCholesky>(kind_);
}

void HessianFactorization::analyze(const HessianLayout& layout) {
  factorized_ = false;
  if (cholmod_)
    cholmod_->analyze(layout.dimension(), layout.columnStart(), layout.rowIndex());
  else
    block_.analyze(layout.blockOffsets(), layout.columnStart(), layout.rowIndex());
}

bool HessianFactorization::factorize(const std::vector<double>& values) {
  factorized_ = cholmod_ ? cholmod_->factorize(values) : block_.factorize(values);
  return factorized_;
}

void HessianFactorization::solve(const double* b, double* x, int ncols) {
  if (cholmod_)
    cholmod_->solve(b, x, ncols);
  else
    block_.solve(b, x, ncols);
}

void HessianFactorization::inverseBlock(const std::vector<int>& scalars, double* out) {
  if (!cholmod_) {
    block_.inverseBlock(scalars, out);
    return;
  }
  const int n = cholmod_->dimension(), m = static_cast<int>(scalars.size());
  Eigen::MatrixXd E = Eigen::MatrixXd::Zero(n, m), X(n, m);
  for (int a = 0; a < m; ++a) E(scalars[a], a) = 1.0;
  cholmod_->solve(E.data(), X.data(), m);
  for (int a = 0; a < m; ++a)
    for (int b = 0; b < m; ++b) out[a + static_cast<long>(b) * m] = X(scalars[a], b);
}

double HessianFactorization::flops() const { return cholmod_ ? cholmod_->flops() : block_.flops(); }

long HessianFactorization::factorNonZeros() const {
  return cholmod_ ? cholmod_->factorNonZeros() : block_.factorNonZeros();
}

}  // namespace loopd
