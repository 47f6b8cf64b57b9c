// Marginal covariances from the Bayes tree.
//
// A clique's conditional is L_FFᵀ·x_F + L_SFᵀ·x_S = d (R = L_FFᵀ, S = L_SFᵀ), so with
// A = R⁻¹·S:   Σ_FS = −A·Σ_SS,   Σ_FF = (RᵀR)⁻¹ + A·Σ_SS·Aᵀ = (RᵀR)⁻¹ − Σ_FS·Aᵀ.
// The separator is contained in the parent clique, so Σ_SS is a sub-block of the parent's
// joint marginal: recursive from the root (where Σ = (RᵀR)⁻¹), cached per clique for the
// current epoch (any update changes every marginal, so the epoch invalidates them all).
// GCC 12 reports a false -Wmaybe-uninitialized inside Eigen's AVX-512 GEMM packing.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include <Eigen/Cholesky>
#include <algorithm>
#include <stdexcept>

#include "solvers/incremental/isam2.h"

namespace loopd {

namespace {
using ConstMatMap = Eigen::Map<const Eigen::MatrixXd, 0, Eigen::OuterStride<>>;
}

int Isam2Backend::varIndex(Key k) const {
  const int v = estimate_.slot(k);
  if (v < 0) throw std::invalid_argument("marginal of unknown variable " + keyToString(k));
  if (cliqueOf_[v] < 0)
    throw std::invalid_argument("marginal of " + keyToString(k) + ", which no factor constrains");
  return v;
}

bool Isam2Backend::marginalDetermined(Key k) const {
  for (int c = cliqueOf_[varIndex(k)]; c >= 0; c = cliques_[c].parent)
    if (cliques_[c].damped) return false;
  return true;
}

bool Isam2Backend::isInRootClique(Key key) const {
  const int v = estimate_.slot(key);
  return v >= 0 && cliqueOf_[v] >= 0 && cliques_[cliqueOf_[v]].parent < 0;
}

void Isam2Backend::computeCliqueMarginal(int c) {
  Clique& C = cliques_[c];
  const int n = C.n, nf = C.nf, ns = n - nf;
  const double* M = C.m.data();
  const ConstMatMap LFF(M, nf, nf, Eigen::OuterStride<>(n));
  // (RᵀR)⁻¹ = (L·Lᵀ)⁻¹ = L⁻ᵀ·L⁻¹
  Eigen::MatrixXd X = Eigen::MatrixXd::Identity(nf, nf);
  LFF.triangularView<Eigen::Lower>().solveInPlace(X);
  Eigen::Map<Eigen::MatrixXd> S(C.marginal.writable(static_cast<size_t>(n) * n), n, n);
  S.topLeftCorner(nf, nf).noalias() = X.transpose() * X;
  if (ns > 0) {
    const Clique& P = cliques_[C.parent];
    const Eigen::Map<const Eigen::MatrixXd> SP(P.marginal.data(), P.n, P.n);
    for (size_t j = 0; j < P.vars.size(); ++j) localIdx_[P.vars[j]] = static_cast<int>(j);
    // Σ_SS from the parent's joint marginal.
    const int nv = static_cast<int>(C.vars.size());
    for (int ia = C.numFrontals; ia < nv; ++ia) {
      const int pa = P.offsets[localIdx_[C.vars[ia]]], oa = C.offsets[ia];
      const int da = C.offsets[ia + 1] - oa;
      for (int ib = C.numFrontals; ib < nv; ++ib) {
        const int pb = P.offsets[localIdx_[C.vars[ib]]], ob = C.offsets[ib];
        const int db = C.offsets[ib + 1] - ob;
        S.block(oa, ob, da, db) = SP.block(pa, pb, da, db);
      }
    }
    for (int v : P.vars) localIdx_[v] = -1;
    // A = R⁻¹·S = L_FF⁻ᵀ·L_SFᵀ
    Eigen::MatrixXd A = ConstMatMap(M + nf, ns, nf, Eigen::OuterStride<>(n)).transpose();
    LFF.transpose().triangularView<Eigen::Upper>().solveInPlace(A);
    S.topRightCorner(nf, ns).noalias() = -A * S.bottomRightCorner(ns, ns);
    S.topLeftCorner(nf, nf).noalias() -= S.topRightCorner(nf, ns) * A.transpose();
    S.bottomLeftCorner(ns, nf) = S.topRightCorner(nf, ns).transpose();
  }
  C.marginalEpoch = epoch_;
}

const double* Isam2Backend::cliqueMarginal(int c) {
  if (cliques_[c].marginalEpoch != epoch_) {
    std::vector<int> chain;
    for (int a = c; a >= 0 && cliques_[a].marginalEpoch != epoch_; a = cliques_[a].parent)
      chain.push_back(a);
    for (size_t i = chain.size(); i-- > 0;) computeCliqueMarginal(chain[i]);
  }
  return cliques_[c].marginal.data();
}

Eigen::MatrixXd Isam2Backend::marginalCovariance(const std::vector<Key>& keys) {
  std::vector<int> vs;
  vs.reserve(keys.size());
  for (Key k : keys) vs.push_back(varIndex(k));
  // Fast path: all keys within one clique (the newest pose lies in the root).
  int home = -1;
  for (int v : vs) {
    const Clique& C = cliques_[cliqueOf_[v]];
    bool all = true;
    for (int u : vs) all = all && std::find(C.vars.begin(), C.vars.end(), u) != C.vars.end();
    if (all) {
      home = cliqueOf_[v];
      break;
    }
  }
  if (home < 0) return marginalCovarianceByPathSolve(keys);
  const Clique& C = cliques_[home];
  const Eigen::Map<const Eigen::MatrixXd> S(cliqueMarginal(home), C.n, C.n);
  std::vector<int> off(vs.size() + 1, 0), src(vs.size());
  for (size_t i = 0; i < vs.size(); ++i) {
    off[i + 1] = off[i] + dims_[vs[i]];
    src[i] = C.offsets[std::find(C.vars.begin(), C.vars.end(), vs[i]) - C.vars.begin()];
  }
  Eigen::MatrixXd out(off.back(), off.back());
  for (size_t i = 0; i < vs.size(); ++i)
    for (size_t j = 0; j < vs.size(); ++j)
      out.block(off[i], off[j], dims_[vs[i]], dims_[vs[j]]) =
          S.block(src[i], src[j], dims_[vs[i]], dims_[vs[j]]);
  return out;
}

std::vector<Eigen::MatrixXd> Isam2Backend::marginals(const std::vector<Key>& keys) {
  std::vector<Eigen::MatrixXd> out;
  out.reserve(keys.size());
  for (Key k : keys) {
    const int v = varIndex(k);
    const int c = cliqueOf_[v];
    const Clique& C = cliques_[c];
    const double* m = cliqueMarginal(c);
    const int i = static_cast<int>(std::find(C.vars.begin(), C.vars.end(), v) - C.vars.begin());
    const int o = C.offsets[i], d = dims_[v];
    out.push_back(Eigen::Map<const Eigen::MatrixXd>(m, C.n, C.n).block(o, o, d, d));
  }
  return out;
}

// Columns of H⁻¹ for the keys: forward Rᵀy = e then backward R·x = y, restricted to the
// cliques on the keys' paths to the root (y vanishes elsewhere, and x on a path depends only
// on x further up).
Eigen::MatrixXd Isam2Backend::marginalCovarianceByPathSolve(const std::vector<Key>& keys) {
  std::vector<int> vs;
  for (Key k : keys) vs.push_back(varIndex(k));
  const long stamp = ++pathCounter_;
  std::vector<int> topDown;
  for (int v : vs) {
    std::vector<int> chain;
    for (int c = cliqueOf_[v]; c >= 0 && cliques_[c].pathStamp != stamp; c = cliques_[c].parent) {
      cliques_[c].pathStamp = stamp;
      chain.push_back(c);
    }
    topDown.insert(topDown.end(), chain.rbegin(), chain.rend());
  }
  // Compact rows for the frontal variables of the path cliques.
  int rows = 0;
  std::vector<int> touched;
  for (int c : topDown) {
    const Clique& C = cliques_[c];
    for (int i = 0; i < C.numFrontals; ++i) {
      scratchPos_[C.vars[i]] = rows + C.offsets[i];
      touched.push_back(C.vars[i]);
    }
    rows += C.nf;
  }
  std::vector<int> colOff(vs.size() + 1, 0);
  for (size_t i = 0; i < vs.size(); ++i) colOff[i + 1] = colOff[i] + dims_[vs[i]];
  const int cols = colOff.back();
  Eigen::MatrixXd Y = Eigen::MatrixXd::Zero(rows, cols);
  for (size_t i = 0; i < vs.size(); ++i)
    for (int t = 0; t < dims_[vs[i]]; ++t) Y(scratchPos_[vs[i]] + t, colOff[i] + t) = 1.0;

  // Forward, bottom-up: y_F = L_FF⁻¹(e_F − Σ contributions), then push −L_SF·y_F upward.
  for (size_t idx = topDown.size(); idx-- > 0;) {
    const Clique& C = cliques_[topDown[idx]];
    const int n = C.n, nf = C.nf;
    const int r0 = scratchPos_[C.vars[0]];
    auto yF = Y.middleRows(r0, nf);
    ConstMatMap(C.m.data(), nf, nf, Eigen::OuterStride<>(n))
        .triangularView<Eigen::Lower>()
        .solveInPlace(yF);
    const ConstMatMap LSF(C.m.data() + nf, n - nf, nf, Eigen::OuterStride<>(n));
    for (size_t i = C.numFrontals; i < C.vars.size(); ++i) {
      const int o = C.offsets[i] - nf, d = dims_[C.vars[i]];
      Y.middleRows(scratchPos_[C.vars[i]], d).noalias() -= LSF.middleRows(o, d) * yF;
    }
  }
  // Backward, top-down: x_F = L_FF⁻ᵀ(y_F − L_SFᵀ·x_S).
  for (int c : topDown) {
    const Clique& C = cliques_[c];
    const int n = C.n, nf = C.nf;
    const int r0 = scratchPos_[C.vars[0]];
    auto xF = Y.middleRows(r0, nf);
    const ConstMatMap LSF(C.m.data() + nf, n - nf, nf, Eigen::OuterStride<>(n));
    for (size_t i = C.numFrontals; i < C.vars.size(); ++i) {
      const int o = C.offsets[i] - nf, d = dims_[C.vars[i]];
      xF.noalias() -= LSF.middleRows(o, d).transpose() * Y.middleRows(scratchPos_[C.vars[i]], d);
    }
    ConstMatMap(C.m.data(), nf, nf, Eigen::OuterStride<>(n))
        .transpose()
        .triangularView<Eigen::Upper>()
        .solveInPlace(xF);
  }
  Eigen::MatrixXd out(cols, cols);
  for (size_t i = 0; i < vs.size(); ++i)
    out.middleRows(colOff[i], dims_[vs[i]]) = Y.middleRows(scratchPos_[vs[i]], dims_[vs[i]]);
  for (int v : touched) scratchPos_[v] = -1;
  return 0.5 * (out + out.transpose());
}

}  // namespace loopd
