#include "solvers/init/sparse_normal_solve.h"

#include <Eigen/Sparse>
#include <stdexcept>

#include "solvers/linear/sparse_cholesky.h"

namespace loopd {

Eigen::MatrixXd solveNormalEquations(int n, const InitTriplets& triplets,
                                     const Eigen::MatrixXd& rhs) {
  Eigen::SparseMatrix<double> H(n, n);
  H.setFromTriplets(triplets.begin(), triplets.end());
  const Eigen::SparseMatrix<double> upper = H.triangularView<Eigen::Upper>();
  std::vector<int> colStart(upper.outerIndexPtr(), upper.outerIndexPtr() + n + 1);
  std::vector<int> rowIndex(upper.innerIndexPtr(), upper.innerIndexPtr() + upper.nonZeros());
  std::vector<double> values(upper.valuePtr(), upper.valuePtr() + upper.nonZeros());
  SparseCholesky cholesky;
  cholesky.analyze(n, colStart, rowIndex, /*natural=*/false);
  if (!cholesky.factorize(values))
    throw std::runtime_error("linear initialisation: singular system");
  Eigen::MatrixXd x(n, rhs.cols());
  cholesky.solve(rhs.data(), x.data(), static_cast<int>(rhs.cols()));
  return x;
}

}  // namespace loopd
