#pragma once
// CHOLMOD Cholesky of a symmetric positive definite matrix given as upper-triangle CSC.
// The symbolic analysis is done once per pattern (the caller's layout is already in a
// fill-reducing order, so CHOLMOD keeps it); each numeric factorization reuses it.
#include <cholmod.h>

#include <vector>

namespace loopd {

/// Block: loopd's block-supernodal Cholesky (block_cholesky.h); the others are CHOLMOD's.
enum class FactorizationKind { Block, Auto, Supernodal, Simplicial };

class SparseCholesky {
 public:
  explicit SparseCholesky(FactorizationKind kind = FactorizationKind::Auto);  // not Block
  ~SparseCholesky();
  SparseCholesky(const SparseCholesky&) = delete;
  SparseCholesky& operator=(const SparseCholesky&) = delete;

  /// Symbolic analysis of the n×n pattern (columnStart has n+1 entries). Keeps the given
  /// order when natural is true, otherwise lets CHOLMOD choose (AMD).
  void analyze(int n, const std::vector<int>& columnStart, const std::vector<int>& rowIndex,
               bool natural = true);
  /// Numeric factorization of values laid out on the analysed pattern. False if the matrix
  /// is not positive definite (numerically).
  bool factorize(const std::vector<double>& values);
  /// x = A⁻¹ b for one or more columns (b, x: n×ncols column-major).
  void solve(const double* b, double* x, int ncols = 1);

  bool analyzed() const { return factor_ != nullptr; }
  int dimension() const { return n_; }
  bool isSupernodal() const;
  double flops() const;
  long factorNonZeros() const;

 private:
  cholmod_common common_;
  cholmod_sparse* matrix_ = nullptr;  // shallow: points into the caller's pattern
  cholmod_factor* factor_ = nullptr;
  int n_ = 0;
  std::vector<int> columnStart_, rowIndex_;
};

}  // namespace loopd
