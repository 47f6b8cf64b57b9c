#pragma once
// Block-supernodal Cholesky of the Gauss–Newton Hessian, a drop-in alternative to
// SparseCholesky for HessianLayout patterns. The analysis (block_symbolic.h) postorders the
// block elimination tree and amalgamates block columns into supernodes stored as dense
// column-major panels; factorize() is left-looking supernodal (descendant updates as dense
// products scattered through a relative map, dense LLT + triangular solve per panel), with
// fixed-size kernels for narrow panels. No heap allocation in factorize() or solve().
#include <vector>

#include "solvers/linear/block_symbolic.h"

namespace loopd {

class BlockCholesky {
 public:
  /// Pattern exactly as HessianLayout gives it: upper-triangle CSC of the n×n scalar matrix
  /// (n = blockOffsets.back()), variable b on scalars [blockOffsets[b], blockOffsets[b+1]),
  /// already in a fill-reducing order; diagonal blocks stored whole (upper part used).
  /// Throws std::invalid_argument for an inconsistent pattern.
  void analyze(const std::vector<int>& blockOffsets, const std::vector<int>& columnStart,
               const std::vector<int>& rowIndex);
  /// Numeric factorization of values on the analysed pattern. False if the matrix is not
  /// (numerically) positive definite; the factor is then unusable until the next success.
  bool factorize(const std::vector<double>& values);
  /// x = H⁻¹ b for ncols columns (n×ncols column-major). x may equal b.
  void solve(const double* b, double* x, int ncols = 1) const;
  /// The entries of H⁻¹ at rows and columns `scalars` (original scalar indices), written
  /// m×m column-major to out. H⁻¹ = L⁻ᵀL⁻¹ (permuted), so (H⁻¹)_ij = y_i·y_j with L y = e: each
  /// y is non-zero only on its supernode's ancestors, so a few variables of a large graph
  /// cost a few short forward sweeps, not full solves. Not const: it uses the object's own
  /// workspaces (no allocation per call), so concurrent calls on one factor are not safe.
  void inverseBlock(const std::vector<int>& scalars, double* out);

  bool analyzed() const { return analyzed_; }
  bool factorized() const { return factorized_; }
  int dimension() const { return sym_.n; }
  int supernodes() const { return sym_.numSupernodes; }
  double flops() const { return sym_.flops; }
  long factorNonZeros() const { return sym_.factorNonZeros; }
  long storedEntries() const { return sym_.panelEntries; }

 private:
  BlockSymbolic sym_;
  bool analyzed_ = false;
  bool factorized_ = false;
  std::vector<double> L_;                // panels
  std::vector<double> update_;           // descendant-update workspace
  std::vector<int> map_;                 // relative map: scalar row → row in the current panel
  std::vector<int> lpos_, head_, next_;  // left-looking descendant lists
  std::vector<int> parent_;              // supernodal elimination tree (−1: a root)
  std::vector<int> position_;            // original scalar → permuted
  std::vector<double> work_;             // inverseBlock: a zeroed permuted vector
  std::vector<int> rowOfSuper_;          // inverseBlock: first gathered row, −1 if unused
};

}  // namespace loopd
