#include "solvers/linear/sparse_cholesky.h"

#include <cstring>
#include <stdexcept>

namespace loopd {

SparseCholesky::SparseCholesky(FactorizationKind kind) {
  cholmod_start(&common_);
  common_.print = 0;
  common_.error_handler = nullptr;
  common_.quick_return_if_not_posdef = 1;
  switch (kind) {
    case FactorizationKind::Block:  // not a CHOLMOD mode; behave as Auto
    case FactorizationKind::Auto:
      common_.supernodal = CHOLMOD_AUTO;
      break;
    case FactorizationKind::Supernodal:
      common_.supernodal = CHOLMOD_SUPERNODAL;
      break;
    case FactorizationKind::Simplicial:
      common_.supernodal = CHOLMOD_SIMPLICIAL;
      break;
  }
  common_.final_ll = 1;
}

SparseCholesky::~SparseCholesky() {
  if (factor_) cholmod_free_factor(&factor_, &common_);
  if (matrix_) {
    // The pattern arrays belong to us (vectors), only free the header.
    matrix_->p = matrix_->i = matrix_->x = nullptr;
    matrix_->nzmax = 0;
    cholmod_free_sparse(&matrix_, &common_);
  }
  cholmod_finish(&common_);
}

void SparseCholesky::analyze(int n, const std::vector<int>& columnStart,
                             const std::vector<int>& rowIndex, bool natural) {
  if (factor_) cholmod_free_factor(&factor_, &common_);
  if (matrix_) {
    matrix_->p = matrix_->i = matrix_->x = nullptr;
    matrix_->nzmax = 0;
    cholmod_free_sparse(&matrix_, &common_);
  }
  n_ = n;
  columnStart_ = columnStart;
  rowIndex_ = rowIndex;
  matrix_ = cholmod_allocate_sparse(n, n, 0, 1, 1, 1, CHOLMOD_PATTERN, &common_);
  if (!matrix_) throw std::runtime_error("CHOLMOD: cannot allocate matrix header");
  // cholmod_allocate_sparse also allocated p (n+1) and i (max(1, nzmax)); free them before
  // pointing the header at our own arrays, or every analyze() leaks them.
  matrix_->p = cholmod_free(static_cast<size_t>(n) + 1, sizeof(int), matrix_->p, &common_);
  matrix_->i = cholmod_free(matrix_->nzmax, sizeof(int), matrix_->i, &common_);
  matrix_->p = columnStart_.data();
  matrix_->i = rowIndex_.data();
  matrix_->nzmax = rowIndex_.size();
  if (natural) {
    common_.nmethods = 1;
    common_.method[0].ordering = CHOLMOD_NATURAL;
    common_.postorder = 1;
  } else {
    common_.nmethods = 1;
    common_.method[0].ordering = CHOLMOD_AMD;
  }
  factor_ = cholmod_analyze(matrix_, &common_);
  if (!factor_ || common_.status < CHOLMOD_OK)
    throw std::runtime_error("CHOLMOD: symbolic analysis failed");
}

bool SparseCholesky::factorize(const std::vector<double>& values) {
  if (!factor_) throw std::logic_error("SparseCholesky::factorize before analyze");
  matrix_->xtype = CHOLMOD_REAL;
  matrix_->x = const_cast<double*>(values.data());
  cholmod_factorize(matrix_, factor_, &common_);
  matrix_->x = nullptr;
  matrix_->xtype = CHOLMOD_PATTERN;
  return common_.status == CHOLMOD_OK && factor_->minor == static_cast<size_t>(n_);
}

void SparseCholesky::solve(const double* b, double* x, int ncols) {
  cholmod_dense B;
  std::memset(&B, 0, sizeof(B));
  B.nrow = n_;
  B.ncol = ncols;
  B.nzmax = static_cast<size_t>(n_) * ncols;
  B.d = n_;
  B.x = const_cast<double*>(b);
  B.xtype = CHOLMOD_REAL;
  B.dtype = CHOLMOD_DOUBLE;
  cholmod_dense* X = cholmod_solve(CHOLMOD_A, factor_, &B, &common_);
  if (!X) throw std::runtime_error("CHOLMOD: solve failed");
  std::memcpy(x, X->x, sizeof(double) * static_cast<size_t>(n_) * ncols);
  cholmod_free_dense(&X, &common_);
}

bool SparseCholesky::isSupernodal() const { return factor_ && factor_->is_super; }
double SparseCholesky::flops() const { return common_.fl; }
long SparseCholesky::factorNonZeros() const { return static_cast<long>(common_.lnz); }

}  // namespace loopd
