#include "solvers/linear/block_cholesky.h"

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

namespace loopd {

namespace {

using Stride = Eigen::OuterStride<>;
using MatMap = Eigen::Map<Eigen::MatrixXd, 0, Stride>;
using ConstMatMap = Eigen::Map<const Eigen::MatrixXd, 0, Stride>;

bool pivotsOk(const double* P, int nr, int nc) {
  for (int i = 0; i < nc; ++i) {
    const double v = P[static_cast<long>(i) * nr + i];
    if (!(v > 0.0) || !std::isfinite(v)) return false;
  }
  return true;
}

// Dense factorization of one panel (nr×nc, leading dimension nr): L11 = chol(A11) in the
// lower part of the top nc×nc block, L21 = A21 L11⁻ᵀ below it.
template <int W>
bool factorPanelFixed(double* P, int nr) {
  using Mat = Eigen::Matrix<double, W, W>;
  Eigen::Map<Mat, 0, Stride> D(P, W, W, Stride(nr));
  Mat M = D;
  // Unblocked lower Cholesky on the register-resident copy.
  for (int k = 0; k < W; ++k) {
    double x = M(k, k);
    for (int t = 0; t < k; ++t) x -= M(k, t) * M(k, t);
    if (!(x > 0.0) || !std::isfinite(x)) return false;
    x = std::sqrt(x);
    M(k, k) = x;
    const double inv = 1.0 / x;
    for (int i = k + 1; i < W; ++i) {
      double y = M(i, k);
      for (int t = 0; t < k; ++t) y -= M(i, t) * M(k, t);
      M(i, k) = y * inv;
    }
  }
  D.template triangularView<Eigen::Lower>() = M;
  if (nr > W) {
    // B ← B·L⁻ᵀ column by column (each column a contiguous, vectorised sweep).
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, W>, 0, Stride> B(P + W, nr - W, W, Stride(nr));
    for (int j = 0; j < W; ++j) {
      auto cj = B.col(j);
      for (int t = 0; t < j; ++t) cj -= M(j, t) * B.col(t);
      cj *= 1.0 / M(j, j);
    }
  }
  return true;
}

// Eigen's level-3 kernels take their packing buffers from the stack (alloca) when they fit in
// EIGEN_STACK_ALLOCATION_LIMIT (128 KiB) and from the heap otherwise; every call below is cut
// into tiles of at most kTile rows, columns and depth so that they always fit: no heap
// allocation, and the packing cost stays ~1% of the tile's flops.
constexpr int kTile = 128;

// C (m×n, ldc) −= A (m×k, lda) · B (n×k, ldb)ᵀ, or C = A·Bᵀ when assign. lowerOnly: entries
// (i, j) with i < j are not needed and whole tiles above the diagonal are skipped.
void gemmNT(int m, int n, int k, const double* A, int lda, const double* B, int ldb, double* C,
            int ldc, bool lowerOnly, bool assign) {
  for (int j0 = 0; j0 < n; j0 += kTile) {
    const int nn = std::min(kTile, n - j0);
    for (int i0 = 0; i0 < m; i0 += kTile) {
      const int mm = std::min(kTile, m - i0);
      if (lowerOnly && i0 + mm <= j0) continue;
      MatMap Ct(C + static_cast<long>(j0) * ldc + i0, mm, nn, Stride(ldc));
      for (int k0 = 0; k0 < k; k0 += kTile) {
        const int kk = std::min(kTile, k - k0);
        ConstMatMap At(A + static_cast<long>(k0) * lda + i0, mm, kk, Stride(lda));
        ConstMatMap Bt(B + static_cast<long>(k0) * ldb + j0, nn, kk, Stride(ldb));
        if (!assign)
          Ct.noalias() -= At * Bt.transpose();
        else if (k0 == 0)
          Ct.noalias() = At * Bt.transpose();
        else
          Ct.noalias() += At * Bt.transpose();
      }
    }
  }
}

// X (m×w, ldx) ← X · L⁻ᵀ for the w×w lower-triangular L (ldl), in row chunks.
void trsmRightLowerT(const double* L, int w, int ldl, double* X, int m, int ldx) {
  ConstMatMap Lm(L, w, w, Stride(ldl));
  for (int i0 = 0; i0 < m; i0 += kTile) {
    MatMap Xt(X + i0, std::min(kTile, m - i0), w, Stride(ldx));
    Lm.triangularView<Eigen::Lower>().solveInPlace(Xt.transpose());
  }
}

// Wide panels: left-looking over column blocks of kPanelBlock (GEMM update of the block
// column from the columns left of it, unblocked LLT of its diagonal block, TRSM below).
constexpr int kPanelBlock = 64;

bool factorPanel(double* P, int nr, int nc) {
  switch (nc) {
    case 2:
      return factorPanelFixed<2>(P, nr);
    case 3:
      return factorPanelFixed<3>(P, nr);
    case 6:
      return factorPanelFixed<6>(P, nr);
    default:
      break;
  }
  for (int k = 0; k < nc; k += kPanelBlock) {
    const int bs = std::min(kPanelBlock, nc - k);
    double* Pk = P + static_cast<long>(k) * nr + k;  // (k, k)
    if (k > 0) gemmNT(nr - k, bs, k, P + k, nr, P + k, nr, Pk, nr, true, false);
    MatMap D(Pk, bs, bs, Stride(nr));
    if (Eigen::internal::llt_inplace<double, Eigen::Lower>::unblocked(D) >= 0) return false;
    if (nr > k + bs) trsmRightLowerT(Pk, bs, nr, Pk + bs, nr - k - bs, nr);
  }
  return pivotsOk(P, nr, nc);
}

// Solve helpers on one panel's diagonal block (lower part, leading dimension nr).
constexpr int kSolveChunk = 256;  // rows per gathered/scattered chunk (stack buffer)

// x ← L11⁻¹ x
void lowerSolve(const double* P, int nr, int nc, double* x) {
  if (nc > 32) {
    Eigen::Map<Eigen::VectorXd> xv(x, nc);
    ConstMatMap(P, nc, nc, Stride(nr)).triangularView<Eigen::Lower>().solveInPlace(xv);
    return;
  }
  for (int j = 0; j < nc; ++j) {
    const double* Lj = P + static_cast<long>(j) * nr;
    const double xj = x[j] / Lj[j];
    x[j] = xj;
    for (int i = j + 1; i < nc; ++i) x[i] -= Lj[i] * xj;
  }
}

// x ← L11⁻ᵀ x
void upperSolve(const double* P, int nr, int nc, double* x) {
  if (nc > 32) {
    Eigen::Map<Eigen::VectorXd> xv(x, nc);
    ConstMatMap(P, nc, nc, Stride(nr)).transpose().triangularView<Eigen::Upper>().solveInPlace(xv);
    return;
  }
  for (int j = nc - 1; j >= 0; --j) {
    const double* Lj = P + static_cast<long>(j) * nr;
    double sum = x[j];
    for (int i = j + 1; i < nc; ++i) sum -= Lj[i] * x[i];
    x[j] = sum / Lj[j];
  }
}

// One supernode's step of the forward solve L y = v (permuted space): its own columns
// through the diagonal block, then their products subtracted from the rows below.
void forwardPanel(const BlockSymbolic& sym, const double* L, int s, double* v) {
  const int c0 = sym.superCol[s], nc = sym.superCol[s + 1] - c0;
  const int* rs = sym.rows.data() + sym.rowStart[s];
  const int nr = sym.rowStart[s + 1] - sym.rowStart[s];
  const double* P = L + sym.valueStart[s];
  double* xs = v + c0;
  lowerSolve(P, nr, nc, xs);
  Eigen::Map<const Eigen::VectorXd> xv(xs, nc);
  for (int i0 = nc; i0 < nr; i0 += kSolveChunk) {
    const int m = std::min(kSolveChunk, nr - i0);
    alignas(64) double tmp[kSolveChunk];
    if (nc <= 8) {  // narrow (2D poses, landmarks): plain column sweeps beat GEMV setup
      const double* Lc = P + i0;
      for (int i = 0; i < m; ++i) tmp[i] = Lc[i] * xs[0];
      for (int c = 1; c < nc; ++c) {
        Lc += nr;
        const double xc = xs[c];
        for (int i = 0; i < m; ++i) tmp[i] += Lc[i] * xc;
      }
    } else {
      Eigen::Map<Eigen::VectorXd> t(tmp, m);
      t.noalias() = ConstMatMap(P + i0, m, nc, Stride(nr)) * xv;
    }
    const int* r = rs + i0;
    for (int i = 0; i < m; ++i) v[r[i]] -= tmp[i];
  }
}

}  // namespace

void BlockCholesky::analyze(const std::vector<int>& blockOffsets,
                            const std::vector<int>& columnStart, const std::vector<int>& rowIndex) {
  analyzed_ = factorized_ = false;
  analyzeBlockPattern(blockOffsets, columnStart, rowIndex, sym_);
  L_.assign(static_cast<size_t>(sym_.panelEntries), 0.0);
  update_.assign(static_cast<size_t>(std::max<long>(sym_.maxUpdate, 1)), 0.0);
  map_.assign(sym_.n, 0);
  lpos_.assign(sym_.numSupernodes, 0);
  head_.assign(sym_.numSupernodes, -1);
  next_.assign(sym_.numSupernodes, -1);
  parent_.assign(sym_.numSupernodes, -1);
  for (int s = 0; s < sym_.numSupernodes; ++s) {
    const int nc = sym_.superCol[s + 1] - sym_.superCol[s];
    if (sym_.rowStart[s + 1] - sym_.rowStart[s] > nc)
      parent_[s] = sym_.superOfCol[sym_.rows[sym_.rowStart[s] + nc]];
  }
  position_.assign(sym_.n, 0);
  for (int k = 0; k < sym_.n; ++k) position_[sym_.scalarPerm.empty() ? k : sym_.scalarPerm[k]] = k;
  work_.assign(sym_.n, 0.0);
  rowOfSuper_.assign(sym_.numSupernodes, -1);
  analyzed_ = true;
}

bool BlockCholesky::factorize(const std::vector<double>& values) {
  if (!analyzed_) throw std::logic_error("BlockCholesky::factorize before analyze");
  if (values.size() != sym_.valueMap.size())
    throw std::invalid_argument("BlockCholesky::factorize: values do not match the pattern");
  factorized_ = false;
  double* L = L_.data();
  std::memset(L, 0, sizeof(double) * L_.size());
  const int* vmap = sym_.valueMap.data();
  const size_t nv = values.size();
  for (size_t k = 0; k < nv; ++k)
    if (vmap[k] >= 0) L[vmap[k]] += values[k];

  const int ns = sym_.numSupernodes;
  const int* rows = sym_.rows.data();
  const int* rowStart = sym_.rowStart.data();
  const int* superCol = sym_.superCol.data();
  const int* superOfCol = sym_.superOfCol.data();
  const long* valueStart = sym_.valueStart.data();
  int* map = map_.data();
  std::fill(head_.begin(), head_.end(), -1);

  for (int s = 0; s < ns; ++s) {
    const int c0 = superCol[s], c1 = superCol[s + 1], nc = c1 - c0;
    const int* rs = rows + rowStart[s];
    const int nr = rowStart[s + 1] - rowStart[s];
    double* Ls = L + valueStart[s];
    for (int i = 0; i < nr; ++i) map[rs[i]] = i;

    // Left-looking: every earlier supernode d with rows in [c0, c1) updates this panel.
    for (int d = head_[s]; d != -1;) {
      const int dnext = next_[d];
      const int* rd = rows + rowStart[d];
      const int ndrow = rowStart[d + 1] - rowStart[d];
      const int ncd = superCol[d + 1] - superCol[d];
      const int pos = lpos_[d];
      int p = pos;
      while (p < ndrow && rd[p] < c1) ++p;
      const int ndrow1 = p - pos, ndrow2 = ndrow - pos;
      const double* Ad = L + valueStart[d] + pos;  // rows pos.. of d's panel
      if (map[rd[ndrow - 1]] - map[rd[pos]] == ndrow2 - 1) {
        // d's remaining rows are a contiguous run of this panel's rows: update in place.
        gemmNT(ndrow2, ndrow1, ncd, Ad, ndrow, Ad, ndrow,
               Ls + static_cast<long>(rd[pos] - c0) * nr + map[rd[pos]], nr, true, false);
      } else {
        double* C = update_.data();
        gemmNT(ndrow2, ndrow1, ncd, Ad, ndrow, Ad, ndrow, C, ndrow2, true, true);
        for (int j = 0; j < ndrow1; ++j) {
          double* col = Ls + static_cast<long>(rd[pos + j] - c0) * nr;
          const double* cc = C + static_cast<long>(j) * ndrow2;
          const int* rr = rd + pos;
          for (int i = j; i < ndrow2; ++i) col[map[rr[i]]] -= cc[i];
        }
      }
      lpos_[d] = p;
      if (p < ndrow) {
        const int t = superOfCol[rd[p]];
        next_[d] = head_[t];
        head_[t] = d;
      }
      d = dnext;
    }

    if (!factorPanel(Ls, nr, nc)) return false;
    lpos_[s] = nc;
    if (nc < nr) {
      const int t = superOfCol[rs[nc]];
      next_[s] = head_[t];
      head_[t] = s;
    }
  }
  factorized_ = true;
  return true;
}

void BlockCholesky::solve(const double* b, double* x, int ncols) const {
  if (!factorized_) throw std::logic_error("BlockCholesky::solve without a successful factorize");
  const int n = sym_.n;
  if (x != b) std::memmove(x, b, sizeof(double) * static_cast<size_t>(n) * ncols);
  const int ns = sym_.numSupernodes;
  const int* rows = sym_.rows.data();
  const int* rowStart = sym_.rowStart.data();
  const int* superCol = sym_.superCol.data();
  const long* valueStart = sym_.valueStart.data();
  const double* L = L_.data();
  const int ncycles = static_cast<int>(sym_.cycleStart.size()) - 1;
  const int* cyc = sym_.cycles.data();
  const int* cycStart = sym_.cycleStart.data();

  for (int col = 0; col < ncols; ++col) {
    double* v = x + static_cast<long>(col) * n;
    // v ← P v (permuted k takes original scalarPerm[k]).
    for (int c = 0; c < ncycles; ++c) {
      const int a = cycStart[c], e = cycStart[c + 1];
      const double tmp = v[cyc[a]];
      for (int i = a; i + 1 < e; ++i) v[cyc[i]] = v[cyc[i + 1]];
      v[cyc[e - 1]] = tmp;
    }
    // Forward: L y = v.
    for (int s = 0; s < ns; ++s) forwardPanel(sym_, L, s, v);
    // Backward: Lᵀ x = y.
    for (int s = ns - 1; s >= 0; --s) {
      const int c0 = superCol[s], nc = superCol[s + 1] - c0;
      const int* rs = rows + rowStart[s];
      const int nr = rowStart[s + 1] - rowStart[s];
      const double* P = L + valueStart[s];
      double* xs = v + c0;
      Eigen::Map<Eigen::VectorXd> xv(xs, nc);
      for (int i0 = nc; i0 < nr; i0 += kSolveChunk) {
        const int m = std::min(kSolveChunk, nr - i0);
        alignas(64) double tmp[kSolveChunk];
        const int* r = rs + i0;
        for (int i = 0; i < m; ++i) tmp[i] = v[r[i]];
        if (nc <= 8) {
          for (int c = 0; c < nc; ++c) {
            const double* Lc = P + static_cast<long>(c) * nr + i0;
            double sum = 0.0;
            for (int i = 0; i < m; ++i) sum += Lc[i] * tmp[i];
            xs[c] -= sum;
          }
        } else {
          xv.noalias() -= ConstMatMap(P + i0, m, nc, Stride(nr)).transpose() *
                          Eigen::Map<const Eigen::VectorXd>(tmp, m);
        }
      }
      upperSolve(P, nr, nc, xs);
    }
    // v ← Pᵀ v.
    for (int c = 0; c < ncycles; ++c) {
      const int a = cycStart[c], e = cycStart[c + 1];
      const double tmp = v[cyc[e - 1]];
      for (int i = e - 1; i > a; --i) v[cyc[i]] = v[cyc[i - 1]];
      v[cyc[a]] = tmp;
    }
  }
}

void BlockCholesky::inverseBlock(const std::vector<int>& scalars, double* out) {
  if (!factorized_)
    throw std::logic_error("BlockCholesky::inverseBlock without a successful factorize");
  const int m = static_cast<int>(scalars.size());
  // The union of the columns' ancestor paths, gathered in supernode order into rows of Y.
  std::vector<int> supers;
  for (int j : scalars) {
    if (j < 0 || j >= sym_.n) throw std::out_of_range("BlockCholesky::inverseBlock: scalar");
    for (int s = sym_.superOfCol[position_[j]]; s >= 0 && rowOfSuper_[s] < 0; s = parent_[s]) {
      rowOfSuper_[s] = 0;
      supers.push_back(s);
    }
  }
  std::sort(supers.begin(), supers.end());
  int rows = 0;
  for (int s : supers) {
    rowOfSuper_[s] = rows;
    rows += sym_.superCol[s + 1] - sym_.superCol[s];
  }
  Eigen::MatrixXd Y = Eigen::MatrixXd::Zero(rows, m);
  double* v = work_.data();
  for (int a = 0; a < m; ++a) {
    const int p = position_[scalars[a]];
    v[p] = 1.0;
    for (int s = sym_.superOfCol[p]; s >= 0; s = parent_[s]) forwardPanel(sym_, L_.data(), s, v);
    for (int s = sym_.superOfCol[p]; s >= 0; s = parent_[s])
      for (int c = sym_.superCol[s]; c < sym_.superCol[s + 1]; ++c) {
        Y(rowOfSuper_[s] + c - sym_.superCol[s], a) = v[c];
        v[c] = 0.0;
      }
  }
  for (int s : supers) rowOfSuper_[s] = -1;
  Eigen::Map<Eigen::MatrixXd>(out, m, m).noalias() = Y.transpose() * Y;
}

}  // namespace loopd
