// The Bayes tree's cliques: their storage, their numerics (a factor linearized into a
// clique's Hessian, a child's separator factor added, the partial Cholesky) and the wildfire
// back-substitution that solves them.
// GCC 12 reports a false -Wmaybe-uninitialized inside Eigen's AVX-512 GEMM packing.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "solvers/incremental/isam2.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <unordered_set>
#include <vector>

namespace loopd {

// ---------------------------------------------------------------------------------------------
// Storage

int Isam2Backend::newClique() {
  int c;
  if (!freeCliques_.empty()) {
    c = freeCliques_.back();
    freeCliques_.pop_back();
  } else {
    c = static_cast<int>(cliques_.size());
    cliques_.emplace_back();
  }
  Clique& C = cliques_[c];
  C.parent = -1;
  C.children.clear();
  C.vars.clear();
  C.offsets.clear();
  C.marginalEpoch = -1;
  C.topStamp = -1;
  C.createdStamp = epoch_;
  C.pathStamp = -1;
  C.alive = true;
  return c;
}

size_t Isam2Backend::cliqueStorageBytes(std::unordered_set<const double*>* seen) const {
  size_t bytes = 0;
  for (const Clique& C : cliques_) {
    if (!C.alive) continue;
    for (const SharedBuffer* b : {&C.m, &C.marginal})
      if (b->data() && (!seen || seen->insert(b->data()).second))
        bytes += b->capacity() * sizeof(double);
  }
  return bytes;
}

void Isam2Backend::freeClique(int c) {
  Clique& C = cliques_[c];
  C.alive = false;
  // Small buffers are kept for the clique slot's next use; large ones go back to the system
  // so peak memory tracks the live tree.
  if (C.m.capacity() > (1u << 20) || C.m.shared()) C.m.release();
  C.marginal.release();
  C.children.clear();
  C.vars.clear();
  C.offsets.clear();
  freeCliques_.push_back(c);
}

// ---------------------------------------------------------------------------------------------
// Numerics

namespace {

using MatMap = Eigen::Map<Eigen::MatrixXd, 0, Eigen::OuterStride<>>;

// H[oa.., ob..] += Jaᵀ·Jb (and the mirrored block when a ≠ b), with compile-time sizes for
// the common shapes (SE2/SE3 between factors, priors, 2D/3D landmark sightings).
template <int D, int DA, int DB>
inline void addJtJFixed(const double* Ja, const double* Jb, double* H, int ld, int oa, int ob,
                        bool mirror) {
  const Eigen::Map<const Eigen::Matrix<double, D, DA>> A(Ja);
  const Eigen::Map<const Eigen::Matrix<double, D, DB>> B(Jb);
  const Eigen::Matrix<double, DA, DB> P = A.transpose() * B;
  Eigen::Map<Eigen::Matrix<double, DA, DB>, 0, Eigen::OuterStride<>> Hab(
      H + static_cast<size_t>(ob) * ld + oa, Eigen::OuterStride<>(ld));
  Hab += P;
  if (mirror) {
    Eigen::Map<Eigen::Matrix<double, DB, DA>, 0, Eigen::OuterStride<>> Hba(
        H + static_cast<size_t>(oa) * ld + ob, Eigen::OuterStride<>(ld));
    Hba += P.transpose();
  }
}

inline void addJtJ(int dim, int da, int db, const double* Ja, const double* Jb, double* H, int ld,
                   int oa, int ob, bool mirror) {
  if (dim == 6 && da == 6 && db == 6) return addJtJFixed<6, 6, 6>(Ja, Jb, H, ld, oa, ob, mirror);
  if (dim == 3 && da == 3 && db == 3) return addJtJFixed<3, 3, 3>(Ja, Jb, H, ld, oa, ob, mirror);
  if (dim == 2 && da == 3 && db == 2) return addJtJFixed<2, 3, 2>(Ja, Jb, H, ld, oa, ob, mirror);
  if (dim == 2 && da == 2 && db == 2) return addJtJFixed<2, 2, 2>(Ja, Jb, H, ld, oa, ob, mirror);
  if (dim == 2 && da == 3 && db == 3) return addJtJFixed<2, 3, 3>(Ja, Jb, H, ld, oa, ob, mirror);
  if (dim == 3 && da == 6 && db == 3) return addJtJFixed<3, 6, 3>(Ja, Jb, H, ld, oa, ob, mirror);
  if (dim == 3 && da == 6 && db == 6) return addJtJFixed<3, 6, 6>(Ja, Jb, H, ld, oa, ob, mirror);
  if (dim == 2 && da == 2 && db == 3) return addJtJFixed<2, 2, 3>(Ja, Jb, H, ld, oa, ob, mirror);
  if (dim == 3 && da == 3 && db == 6) return addJtJFixed<3, 3, 6>(Ja, Jb, H, ld, oa, ob, mirror);
  for (int j = 0; j < db; ++j)
    for (int i = 0; i < da; ++i) {
      double s = 0.0;
      for (int k = 0; k < dim; ++k) s += Ja[i * dim + k] * Jb[j * dim + k];
      H[static_cast<size_t>(ob + j) * ld + oa + i] += s;
      if (mirror) H[static_cast<size_t>(oa + i) * ld + ob + j] += s;
    }
}

}  // namespace

void Isam2Backend::linearizeInto(int factor, Clique& C) {
  const Factor& f = *factors_[factor];
  const int nk = f.size(), dim = f.dim();
  const auto& fv = factorVars_[factor];
  const double* x[kMaxFactorKeys];
  double r[kMaxResidualDim];
  JacobianBlock J[kMaxFactorKeys];
  double* Jp[kMaxFactorKeys];
  for (int k = 0; k < nk; ++k) {
    x[k] = theta_.data(fv[k]);
    Jp[k] = J[k].data();
  }
  f.evaluate(x, r, Jp);
  const int n = C.n;
  double* H = C.m.data();
  double* b = H + static_cast<size_t>(n) * n;
  int off[kMaxFactorKeys], dims[kMaxFactorKeys];
  for (int a = 0; a < nk; ++a) {
    off[a] = C.offsets[localIdx_[fv[a]]];
    dims[a] = dims_[fv[a]];
  }
  for (int a = 0; a < nk; ++a) {
    const double* Ja = J[a].data();
    for (int i = 0; i < dims[a]; ++i) {
      double s = 0.0;
      for (int k = 0; k < dim; ++k) s += Ja[i * dim + k] * r[k];
      b[off[a] + i] -= s;
    }
    // Lower triangle only: the block goes below the diagonal (row offset ≥ column offset).
    for (int bb = a; bb < nk; ++bb) {
      if (off[a] >= off[bb])
        addJtJ(dim, dims[a], dims[bb], Ja, J[bb].data(), H, n, off[a], off[bb], false);
      else
        addJtJ(dim, dims[bb], dims[a], J[bb].data(), Ja, H, n, off[bb], off[a], false);
    }
  }
}

void Isam2Backend::accumulateChild(const Clique& child, Clique& C) {
  // The child's separator factor (lower triangle) scattered into C's lower triangle. Child
  // and parent order their variables by elimination position, so blocks normally stay below
  // the diagonal; an orphan's older order may not, and then the block goes in transposed.
  const int cn = child.n, n = C.n;
  const double* Hc = child.m.data();
  const double* bc = Hc + static_cast<size_t>(cn) * cn;
  double* H = C.m.data();
  double* b = H + static_cast<size_t>(n) * n;
  const int first = child.numFrontals, nv = static_cast<int>(child.vars.size());
  int po[64], *dest = po;
  std::vector<int> big;
  if (nv - first > 64) {
    big.resize(nv - first);
    dest = big.data();
  }
  bool monotone = true;
  for (int k = first; k < nv; ++k) {
    dest[k - first] = C.offsets[localIdx_[child.vars[k]]];
    if (k > first && dest[k - first] <= dest[k - first - 1]) monotone = false;
  }
  const int cnf = child.nf, ns = cn - cnf;
  for (int k = first; k < nv; ++k) {
    const int ck = child.offsets[k], d = child.offsets[k + 1] - ck, pk = dest[k - first];
    for (int i = 0; i < d; ++i) b[pk + i] += bc[ck + i];
  }
  if (monotone) {
    // Contiguous runs of rows: child rows [start, end) land at parent rows from `to`.
    int runStart[65], runTo[65], *rs = runStart, *rt = runTo;
    std::vector<int> bigRuns;
    if (nv - first > 64) {
      bigRuns.resize(2 * (nv - first + 1));
      rs = bigRuns.data();
      rt = bigRuns.data() + (nv - first + 1);
    }
    int runs = 0;
    for (int k = first; k < nv; ++k) {
      const int ck = child.offsets[k] - cnf, pk = dest[k - first];
      if (runs == 0 || rt[runs - 1] + (ck - rs[runs - 1]) != pk) {
        rs[runs] = ck;
        rt[runs] = pk;
        ++runs;
      }
    }
    rs[runs] = ns;
    int run = 0;
    for (int j = 0; j < ns; ++j) {  // child separator column j (lower part: rows ≥ j)
      while (rs[run + 1] <= j) ++run;
      const double* src = Hc + static_cast<size_t>(cnf + j) * cn + cnf;
      const int pj = rt[run] + (j - rs[run]);
      double* dstCol = H + static_cast<size_t>(pj) * n;
      for (int r = run, i0 = j; r < runs; ++r, i0 = rs[r]) {
        const int i1 = rs[r + 1];
        double* dst = dstCol + rt[r] + (i0 - rs[r]);
        const double* sp = src + i0;
        for (int i = 0; i < i1 - i0; ++i) dst[i] += sp[i];
      }
    }
    return;
  }
  for (int kb = first; kb < nv; ++kb) {
    const int cb = child.offsets[kb], db = child.offsets[kb + 1] - cb, pb = dest[kb - first];
    // Diagonal block: lower triangle.
    for (int j = 0; j < db; ++j) {
      const double* src = Hc + static_cast<size_t>(cb + j) * cn + cb;
      double* dst = H + static_cast<size_t>(pb + j) * n + pb;
      for (int i = j; i < db; ++i) dst[i] += src[i];
    }
    for (int ka = kb + 1; ka < nv; ++ka) {
      const int ca = child.offsets[ka], da = child.offsets[ka + 1] - ca, pa = dest[ka - first];
      if (pa > pb) {
        for (int j = 0; j < db; ++j) {
          const double* src = Hc + static_cast<size_t>(cb + j) * cn + ca;
          double* dst = H + static_cast<size_t>(pb + j) * n + pa;
          for (int i = 0; i < da; ++i) dst[i] += src[i];
        }
      } else {
        for (int j = 0; j < db; ++j) {
          const double* src = Hc + static_cast<size_t>(cb + j) * cn + ca;
          for (int i = 0; i < da; ++i) H[static_cast<size_t>(pa + i) * n + pb + j] += src[i];
        }
      }
    }
  }
}

bool Isam2Backend::factorizeClique(Clique& C) {
  const int n = C.n, nf = C.nf, ns = n - nf;
  double* M = C.m.data();
  MatMap H(M, n, n, Eigen::OuterStride<>(n));
  Eigen::Ref<Eigen::MatrixXd> HFF = H.topLeftCorner(nf, nf);
  Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(HFF);
  if (llt.info() != Eigen::Success) return false;
  Eigen::Map<Eigen::VectorXd> bF(M + static_cast<size_t>(n) * n, nf);
  HFF.triangularView<Eigen::Lower>().solveInPlace(bF);
  if (ns > 0) {
    Eigen::Ref<Eigen::MatrixXd> HSF = H.bottomLeftCorner(ns, nf);
    HFF.transpose().triangularView<Eigen::Upper>().solveInPlace<Eigen::OnTheRight>(
        HSF);  // H_SF·L_FF⁻ᵀ
    Eigen::Ref<Eigen::MatrixXd> HSS = H.bottomRightCorner(ns, ns);
    HSS.selfadjointView<Eigen::Lower>().rankUpdate(HSF, -1.0);
    Eigen::Map<Eigen::VectorXd> bS(M + static_cast<size_t>(n) * n + nf, ns);
    bS.noalias() -= HSF * bF;
  }
  return true;
}

// ---------------------------------------------------------------------------------------------
// Wildfire back-substitution

void Isam2Backend::backSubstitute(std::vector<Key>* moved) {
  std::vector<int> stack(newRoots_.begin(), newRoots_.end());
  while (!stack.empty()) {
    const int c = stack.back();
    stack.pop_back();
    const Clique& C = cliques_[c];
    const bool isNew = C.createdStamp == epoch_;
    bool separatorChanged = false;
    for (size_t i = C.numFrontals; i < C.vars.size() && !separatorChanged; ++i)
      separatorChanged = changedStamp_[C.vars[i]] == epoch_;
    if (!isNew && !separatorChanged) continue;
    const bool frontalChanged = solveClique(C, moved);
    ++stats_.solvedCliques;
    // A child's separator lies in this clique's variables: if none of them moved by more
    // than α, only the children re-eliminated in this update need solving.
    const bool all = frontalChanged || separatorChanged;
    for (int ch : C.children)
      if (all || cliques_[ch].createdStamp == epoch_) stack.push_back(ch);
  }
}

bool Isam2Backend::solveClique(const Clique& C, std::vector<Key>* moved) {
  const int n = C.n, nf = C.nf, ns = n - nf;
  const double* M = C.m.data();
  if (static_cast<int>(scratch_.size()) < n) scratch_.resize(n);
  // rhs = d − L_SFᵀ·Δ_S (one dot product per frontal column), then Lᵀ·x = rhs backwards.
  // Hand-written: the frontal blocks are small, so Eigen's dynamic kernels cost more in
  // dispatch than in arithmetic here.
  double* x = scratch_.data();
  const double* d = M + static_cast<size_t>(n) * n;
  if (ns > 0) {
    double* xs = scratch_.data() + nf;
    for (size_t i = C.numFrontals; i < C.vars.size(); ++i) {
      const int o = C.offsets[i] - nf, v = C.vars[i];
      std::memcpy(xs + o, &delta_[static_cast<size_t>(v) * kMaxVarDim], sizeof(double) * dims_[v]);
    }
    for (int i = 0; i < nf; ++i) {
      const double* col = M + static_cast<size_t>(i) * n + nf;  // L_SF(:, i)
      double s = 0.0;
      for (int k = 0; k < ns; ++k) s += col[k] * xs[k];
      x[i] = d[i] - s;
    }
  } else {
    for (int i = 0; i < nf; ++i) x[i] = d[i];
  }
  for (int i = nf - 1; i >= 0; --i) {  // Lᵀ is upper triangular: row i of Lᵀ is column i of L
    const double* col = M + static_cast<size_t>(i) * n;
    double s = x[i];
    for (int k = i + 1; k < nf; ++k) s -= col[k] * x[k];
    x[i] = s / col[i];
  }
  bool anyChanged = false;
  for (int i = 0; i < C.numFrontals; ++i) {
    const int v = C.vars[i], d = dims_[v];
    double* dv = &delta_[static_cast<size_t>(v) * kMaxVarDim];
    const double* nv = &scratch_[C.offsets[i]];
    double change = 0.0, size = 0.0;
    for (int j = 0; j < d; ++j) {
      change = std::max(change, std::abs(nv[j] - dv[j]));
      size = std::max(size, std::abs(nv[j]));
      dv[j] = nv[j];
    }
    if (change > isam_.wildfireThreshold) {
      changedStamp_[v] = epoch_;
      anyChanged = true;
    }
    if (change > 0.0) {
      if (guarding_) recordBeforeStep(v);
      std::memcpy(estimate_.data(v), theta_.data(v), sizeof(double) * kValueStride);
      estimate_.retract(v, dv);
    }
    if (moved && change > options_.moveThreshold && movedStamp_[v] != epoch_) {
      movedStamp_[v] = epoch_;
      moved->push_back(estimate_.key(v));
    }
    if (isam_.urgentRelinearizeThreshold > 0.0 && size >= isam_.urgentRelinearizeThreshold)
      relinearizeNext_ = true;
    if (size >= isam_.relinearizeThreshold && !relinCandidate_[v]) {
      relinCandidate_[v] = 1;
      relinCandidates_.push_back(v);
    }
  }
  return anyChanged;
}

}  // namespace loopd
