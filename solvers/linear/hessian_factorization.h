#pragma once
// The Cholesky factorization the batch solvers use for a HessianLayout's matrix: the
// block-supernodal one (default, fastest on pose graphs) or CHOLMOD (for comparison).
#include <memory>
#include <vector>

#include "solvers/linear/block_cholesky.h"
#include "solvers/linear/hessian_layout.h"
#include "solvers/linear/sparse_cholesky.h"

namespace loopd {

class HessianFactorization {
 public:
  /// kind: Block, or a CHOLMOD variant (Auto, Supernodal, Simplicial).
  explicit HessianFactorization(FactorizationKind kind = FactorizationKind::Block);

  void analyze(const HessianLayout& layout);
  /// False if the matrix is not (numerically) positive definite.
  bool factorize(const std::vector<double>& values);
  /// x = H⁻¹b for ncols columns (column-major n×ncols).
  void solve(const double* b, double* x, int ncols = 1);
  /// (H⁻¹) at rows and columns `scalars`, m×m column-major into out (the block factor's
  /// ancestor-path sweeps; CHOLMOD: full solves of the unit columns).
  void inverseBlock(const std::vector<int>& scalars, double* out);

  /// Whether the last factorize() succeeded (solve() and inverseBlock() need it).
  bool factorized() const { return factorized_; }
  FactorizationKind kind() const { return kind_; }
  double flops() const;
  long factorNonZeros() const;

 private:
  FactorizationKind kind_;
  bool factorized_ = false;
  BlockCholesky block_;
  std::unique_ptr<SparseCholesky> cholmod_;
};

}  // namespace loopd
