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
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, W>, 0, Stride> B(P + W, nr - W, W, Stride(nr));
    M.template triangularView<Eigen::Lower>().solveInPlace(B.transpose());
  }
  return true;
}

bool factorPanel(double* P, int nr, int nc) {
  switch (nc) {
    case 2: return factorPanelFixed<2>(P, nr);
    case 3: return factorPanelFixed<3>(P, nr);
    case 6: return factorPanelFixed<6>(P, nr);
    default: break;
  }
  MatMap D(P, nc, nc, Stride(nr));
  if (Eigen::internal::llt_inplace<double, Eigen::Lower>::blocked(D) >= 0) return false;
  if (!pivotsOk(P, nr, nc)) return false;
  if (nr > nc) {
    MatMap B(P + nc, nr - nc, nc, Stride(nr));
    D.triangularView<Eigen::Lower>().solveInPlace(B.transpose());
  }
  return true;
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
      ConstMatMap A(L + valueStart[d] + pos, ndrow2, ncd, Stride(ndrow));
      const auto B = A.topRows(ndrow1);
      if (map[rd[ndrow - 1]] - map[rd[pos]] == ndrow2 - 1) {
        // d's remaining rows are a contiguous run of this panel's rows: update in place.
        MatMap T(Ls + static_cast<long>(rd[pos] - c0) * nr + map[rd[pos]], ndrow2, ndrow1,
                 Stride(nr));
        T.noalias() -= A * B.transpose();
      } else {
        MatMap C(update_.data(), ndrow2, ndrow1, Stride(ndrow2));
        C.noalias() = A * B.transpose();
        for (int j = 0; j < ndrow1; ++j) {
          double* col = Ls + static_cast<long>(rd[pos + j] - c0) * nr;
          const double* cc = C.data() + static_cast<long>(j) * ndrow2;
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
    for (int s = 0; s < ns; ++s) {
      const int c0 = superCol[s], nc = superCol[s + 1] - c0;
      const int* rs = rows + rowStart[s];
      const int nr = rowStart[s + 1] - rowStart[s];
      const double* P = L + valueStart[s];
      ConstMatMap D(P, nc, nc, Stride(nr));
      Eigen::Map<Eigen::VectorXd> xs(v + c0, nc);
      D.triangularView<Eigen::Lower>().solveInPlace(xs);
      for (int c = 0; c < nc; ++c) {
        const double xc = xs[c];
        const double* Lc = P + static_cast<long>(c) * nr;
        for (int i = nc; i < nr; ++i) v[rs[i]] -= Lc[i] * xc;
      }
    }
    // Backward: Lᵀ x = y.
    for (int s = ns - 1; s >= 0; --s) {
      const int c0 = superCol[s], nc = superCol[s + 1] - c0;
      const int* rs = rows + rowStart[s];
      const int nr = rowStart[s + 1] - rowStart[s];
      const double* P = L + valueStart[s];
      Eigen::Map<Eigen::VectorXd> xs(v + c0, nc);
      for (int c = 0; c < nc; ++c) {
        const double* Lc = P + static_cast<long>(c) * nr;
        double sum = 0.0;
        for (int i = nc; i < nr; ++i) sum += Lc[i] * v[rs[i]];
        xs[c] -= sum;
      }
      ConstMatMap D(P, nc, nc, Stride(nr));
      D.triangularView<Eigen::Lower>().transpose().solveInPlace(xs);
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

}  // namespace loopd
