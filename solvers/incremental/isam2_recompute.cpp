// Re-elimination of the top: recompute() detaches the cliques an update touches, orders
// their variables (CCOLAMD, newest last, grouped by recency when that costs little fill),
// builds new cliques from a symbolic elimination and factorizes them.
#include "solvers/incremental/isam2.h"

#include <ccolamd.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace loopd {

namespace {

// The top's rows as lists of columns (Top::rowPtr, rowCol), the columns' start in CCOLAMD's
// input, and CCOLAMD's workspace.
struct TopPattern {
  int nrow = 0, ncol = 0;
  const std::vector<int>& rowPtr;
  const std::vector<int>& rowCol;
  std::vector<int> colPtr, A, p;
};

// CCOLAMD with constraint groups (null: unconstrained); false if it failed.
bool runCcolamd(TopPattern& t, const int* cmember, std::vector<int>& out) {
  const int nrow = t.nrow, m = t.ncol;
  std::vector<int> fill(t.colPtr.begin(), t.colPtr.end() - 1);
  for (int r = 0; r < nrow; ++r)
    for (int i = t.rowPtr[r]; i < t.rowPtr[r + 1]; ++i) t.A[fill[t.rowCol[i]]++] = r;
  std::copy(t.colPtr.begin(), t.colPtr.end(), t.p.begin());
  double knobs[CCOLAMD_KNOBS];
  int statsOut[CCOLAMD_STATS];
  ccolamd_set_defaults(knobs);
  if (!ccolamd(nrow, m, static_cast<int>(t.A.size()), t.A.data(), t.p.data(), knobs, statsOut,
               const_cast<int*>(cmember)))
    return false;
  out.assign(t.p.begin(), t.p.begin() + m);
  return true;
}

// Elimination work of an ordering: Σ over variables of dim · (dim of its column)², from
// a symbolic elimination (a variable's structure: its rows' later variables and its
// elimination-tree children's). Column c's variable is vars[c], of dimension dims[vars[c]].
double eliminationCost(const TopPattern& t, const std::vector<int>& ord,
                       const std::vector<int>& vars, const std::vector<int>& dims) {
  const int nrow = t.nrow, m = t.ncol;
  const std::vector<int>& rowPtr = t.rowPtr;
  const std::vector<int>& rowCol = t.rowCol;
  std::vector<int> pos(m), homeHead(m, -1), homeNext(nrow, -1);
  for (int k = 0; k < m; ++k) pos[ord[k]] = k;
  for (int r = 0; r < nrow; ++r) {
    int h = m;
    for (int i = rowPtr[r]; i < rowPtr[r + 1]; ++i) h = std::min(h, pos[rowCol[i]]);
    homeNext[r] = homeHead[h];
    homeHead[h] = r;
  }
  std::vector<std::vector<int>> st(m);
  std::vector<int> childHead(m, -1), childNext(m, -1), mark(m, -1);
  double cost = 0.0;
  for (int k = 0; k < m; ++k) {
    std::vector<int>& sk = st[k];
    mark[k] = k;
    int first = m, width = 0;
    auto add = [&](int q) {
      if (mark[q] != k) {
        mark[q] = k;
        sk.push_back(q);
        first = std::min(first, q);
        width += dims[vars[ord[q]]];
      }
    };
    for (int r = homeHead[k]; r >= 0; r = homeNext[r])
      for (int i = rowPtr[r]; i < rowPtr[r + 1]; ++i) add(pos[rowCol[i]]);
    for (int c = childHead[k]; c >= 0; c = childNext[c]) {
      for (int q : st[c]) add(q);
      std::vector<int>().swap(st[c]);
    }
    const double d = dims[vars[ord[k]]];
    cost += d * (d + width) * (d + width);
    if (first < m) {
      childNext[k] = childHead[first];
      childHead[first] = k;
    }
  }
  return cost;
}

}  // namespace

void Isam2Backend::Top::clear() {
  for (std::vector<int>* list : {&vars, &orphans, &factors, &rowPtr, &rowCol, &ov, &homeStart,
                                 &homeRows, &etParent, &created})
    list->clear();
  // structure's inner lists are emptied as symbolicEliminate reuses them.
}

void Isam2Backend::recompute() {
  Top& top = top_;
  top.clear();
  detachTop(top);
  if (top.vars.empty()) return;
  collectTopFactors(top);
  orderTop(top);
  symbolicEliminate(top);
  buildCliques(top);
  eliminateCliques(top);
  for (int v : top.vars) scratchPos_[v] = -1;
}

// 1. The top: cliques holding affected variables, and all their ancestors.
void Isam2Backend::detachTop(Top& top) {
  std::vector<int> topCliques;
  auto listVar = [&](int v) {
    if (scratchPos_[v] >= 0 || varFactors_[v].empty()) return;
    scratchPos_[v] = static_cast<int>(top.vars.size());
    top.vars.push_back(v);
  };
  for (int v : affected_) {
    int c = cliqueOf_[v];
    if (c < 0) {
      listVar(v);
      continue;
    }
    while (c >= 0 && cliques_[c].topStamp != epoch_) {
      cliques_[c].topStamp = epoch_;
      topCliques.push_back(c);
      c = cliques_[c].parent;
    }
  }
  for (int c : topCliques) {
    const Clique& C = cliques_[c];
    for (int i = 0; i < C.numFrontals; ++i) {
      const int v = C.vars[i];
      cliqueOf_[v] = -1;
      listVar(v);
      if (varFactors_[v].empty())  // no factor left: leaves the tree, estimate kept
        std::fill_n(&delta_[static_cast<size_t>(v) * kMaxVarDim], kMaxVarDim, 0.0);
    }
    for (int ch : C.children)
      if (cliques_[ch].topStamp != epoch_) top.orphans.push_back(ch);
  }
  if (!topCliques.empty()) {
    roots_.erase(std::remove_if(roots_.begin(), roots_.end(),
                                [&](int c) { return cliques_[c].topStamp == epoch_; }),
                 roots_.end());
    for (int c : topCliques) freeClique(c);
  }
  for (int o : top.orphans) cliques_[o].parent = -1;
  newRoots_.clear();
  stats_.topCliques = static_cast<int>(topCliques.size());
  stats_.topVariables = static_cast<int>(top.vars.size());
  stats_.orphans = static_cast<int>(top.orphans.size());
}

// 2. The rows of the top: factors entirely inside it, and the orphans' separator factors,
//    each as its columns (positions in top.vars, which scratchPos_ holds until orderTop).
void Isam2Backend::collectTopFactors(Top& top) {
  for (int v : top.vars)
    for (int f : varFactors_[v]) {
      if (factorStamp_[f] == epoch_) continue;
      factorStamp_[f] = epoch_;
      bool inside = true;
      for (int k = 0; k < factors_[f]->size() && inside; ++k)
        inside = scratchPos_[factorVars_[f][k]] >= 0;
      if (inside) top.factors.push_back(f);
    }
  const size_t nrow = top.factors.size() + top.orphans.size();
  top.rowPtr.assign(nrow + 1, 0);
  top.rowCol.reserve(nrow * 3);
  for (size_t r = 0; r < top.factors.size(); ++r) {
    const int f = top.factors[r];
    for (int k = 0; k < factors_[f]->size(); ++k)
      top.rowCol.push_back(scratchPos_[factorVars_[f][k]]);
    top.rowPtr[r + 1] = static_cast<int>(top.rowCol.size());
  }
  for (size_t o = 0; o < top.orphans.size(); ++o) {
    const Clique& O = cliques_[top.orphans[o]];
    for (size_t i = O.numFrontals; i < O.vars.size(); ++i)
      top.rowCol.push_back(scratchPos_[O.vars[i]]);
    top.rowPtr[top.factors.size() + o + 1] = static_cast<int>(top.rowCol.size());
  }
}

// 3. Constrained ordering (CCOLAMD): variables of the new factors last.
void Isam2Backend::orderTop(Top& top) {
  const std::vector<int>& topVars = top.vars;
  const int m = static_cast<int>(topVars.size());
  std::vector<int> order(m);
  if (m <= 2) {
    int next = 0;
    for (int pass = 0; pass < 2; ++pass)
      for (int i = 0; i < m; ++i)
        if ((constrainedStamp_[topVars[i]] == epoch_) == (pass == 1)) order[next++] = i;
  } else {
    const int nrow = static_cast<int>(top.rowPtr.size()) - 1;
    TopPattern t{nrow, m, top.rowPtr, top.rowCol, {}, {}, {}};
    const int nnz = static_cast<int>(t.rowCol.size());
    t.colPtr.assign(m + 1, 0);
    for (int c : t.rowCol) ++t.colPtr[c + 1];
    for (int j = 0; j < m; ++j) t.colPtr[j + 1] += t.colPtr[j];
    t.A.resize(ccolamd_recommended(nnz, nrow, m));
    t.p.resize(m + 1);
    // Groups: the variables of the new factors last (they form the new root, so the next
    // update stays small); with recencyGrouping, variables no new factor has touched for
    // that many updates first, so they sink below the part of the tree that updates keep
    // visiting instead of staying on its path to the root — kept only if it costs little
    // more fill than the plain order.
    // grouped: 2 constrained, 0 old, 1 recent (the recency constraint's groups).
    std::vector<int> cmember(m, 0), grouped(m, 1);
    bool anyConstrained = false, allConstrained = true, anyRecent = false;
    int numOld = 0;
    for (int i = 0; i < m; ++i) {
      const bool c = constrainedStamp_[topVars[i]] == epoch_;
      cmember[i] = c ? 1 : 0;
      anyConstrained |= c;
      allConstrained &= c;
      if (c) {
        grouped[i] = 2;
      } else if (updateCount_ - touched_[topVars[i]] > isam_.recencyGrouping) {
        grouped[i] = 0;
        ++numOld;
      } else {
        anyRecent = true;
      }
    }
    const bool twoGroups = anyConstrained && !allConstrained;
    bool ok = runCcolamd(t, twoGroups ? cmember.data() : nullptr, order);
    // Only where old variables are a sizeable part of the top (a quarter or more): where
    // closures keep returning everywhere (city10000) the constraint buys nothing and its
    // extra fill costs time.
    if (ok && isam_.recencyGrouping > 0 && anyRecent && 4 * numOld >= m) {
      std::vector<int> alt;
      if (!anyConstrained)
        for (int& g : grouped) g = std::min(g, 1);
      if (runCcolamd(t, grouped.data(), alt) &&
          eliminationCost(t, alt, topVars, dims_) <=
              isam_.recencyFillTolerance * eliminationCost(t, order, topVars, dims_))
        order.swap(alt);
    }
    if (!ok)
      for (int k = 0; k < m; ++k) order[k] = k;
  }
  top.ov.resize(m);  // variable at each position
  for (int k = 0; k < m; ++k) top.ov[k] = topVars[order[k]];
  for (int k = 0; k < m; ++k) scratchPos_[top.ov[k]] = k;
}

// 4. Symbolic elimination: each row's home is its first-eliminated variable; the structure
//    of a variable's column is its rows' later variables plus its etree children's.
void Isam2Backend::symbolicEliminate(Top& top) {
  const int m = static_cast<int>(top.vars.size());
  std::vector<int>& homeStart = top.homeStart;
  std::vector<int>& homeRows = top.homeRows;
  homeStart.assign(m + 1, 0);
  const int nrows = static_cast<int>(top.rowPtr.size()) - 1;
  // A row's columns index top.vars; their positions in the order:
  std::vector<int> posOfColumn(m);
  for (int c = 0; c < m; ++c) posOfColumn[c] = scratchPos_[top.vars[c]];
  std::vector<int> rowHome(nrows);
  for (int r = 0; r < nrows; ++r) {
    int h = m;
    for (int i = top.rowPtr[r]; i < top.rowPtr[r + 1]; ++i)
      h = std::min(h, posOfColumn[top.rowCol[i]]);
    rowHome[r] = h;
    ++homeStart[h + 1];
  }
  for (int k = 0; k < m; ++k) homeStart[k + 1] += homeStart[k];
  homeRows.resize(nrows);
  {
    std::vector<int> fill(homeStart.begin(), homeStart.end() - 1);
    for (int r = 0; r < nrows; ++r) homeRows[fill[rowHome[r]]++] = r;
  }
  std::vector<std::vector<int>>& structure = top.structure;
  if (static_cast<int>(structure.size()) < m) structure.resize(m);
  for (int k = 0; k < m; ++k) structure[k].clear();
  top.etParent.assign(m, -1);
  std::vector<int> childHead(m, -1), childNext(m, -1), mark(m, -1);
  for (int k = 0; k < m; ++k) {
    std::vector<int>& s = structure[k];
    mark[k] = k;
    auto add = [&](int q) {
      if (mark[q] != k) {
        mark[q] = k;
        s.push_back(q);
      }
    };
    for (int i = homeStart[k]; i < homeStart[k + 1]; ++i) {
      const int r = homeRows[i];
      for (int j = top.rowPtr[r]; j < top.rowPtr[r + 1]; ++j) add(posOfColumn[top.rowCol[j]]);
    }
    for (int c = childHead[k]; c >= 0; c = childNext[c])
      for (int q : structure[c]) add(q);
    std::sort(s.begin(), s.end());
    if (!s.empty()) {
      top.etParent[k] = s.front();
      childNext[k] = childHead[s.front()];
      childHead[s.front()] = k;
    }
  }
}

// 5. Cliques, from the root down: a variable joins its parent's clique when its structure
//    is exactly that clique's variables.
void Isam2Backend::buildCliques(Top& top) {
  const int m = static_cast<int>(top.vars.size());
  const std::vector<std::vector<int>>& structure = top.structure;
  std::vector<int>& created = top.created;
  std::vector<int> cliqueAt(m, -1);
  std::vector<int> firstFrontal;  // per created clique (index in `created`)
  // clique id → index in created: a member kept all −1 between updates (a per-update vector
  // the size of the tree would cost O(n) per update).
  std::vector<int>& createdIndex = createdIndex_;
  for (int k = m - 1; k >= 0; --k) {
    const int p = top.etParent[k];
    if (p >= 0) {
      const int C = cliqueAt[p];
      const int ci = createdIndex[C];
      if (firstFrontal[ci] == p && structure[k].size() == structure[p].size() + 1) {
        cliques_[C].vars.push_back(top.ov[k]);  // frontals collected last-eliminated first
        ++cliques_[C].numFrontals;
        firstFrontal[ci] = k;
        cliqueAt[k] = C;
        continue;
      }
    }
    const int c = newClique();
    if (createdIndex.size() < cliques_.size()) createdIndex.resize(cliques_.size(), -1);
    createdIndex[c] = static_cast<int>(created.size());
    created.push_back(c);
    firstFrontal.push_back(k);
    Clique& C = cliques_[c];
    C.vars.push_back(top.ov[k]);
    C.numFrontals = 1;
    C.parent = p >= 0 ? cliqueAt[p] : -1;
    cliqueAt[k] = c;
  }
  for (int c : created) createdIndex[c] = -1;
  for (size_t i = 0; i < created.size(); ++i) {
    const int c = created[i];
    Clique& C = cliques_[c];
    std::reverse(C.vars.begin(), C.vars.end());
    // Separator = structure of the last frontal.
    const int last = scratchPos_[C.vars.back()];
    for (int q : structure[last]) C.vars.push_back(top.ov[q]);
    C.offsets.resize(C.vars.size() + 1);
    C.offsets[0] = 0;
    for (size_t j = 0; j < C.vars.size(); ++j) C.offsets[j + 1] = C.offsets[j] + dims_[C.vars[j]];
    C.nf = C.offsets[C.numFrontals];
    C.n = C.offsets.back();
    for (int j = 0; j < C.numFrontals; ++j) cliqueOf_[C.vars[j]] = c;
    if (C.parent >= 0)
      cliques_[C.parent].children.push_back(c);
    else
      newRoots_.push_back(c);
  }
  for (int o : top.orphans) {
    Clique& O = cliques_[o];
    int h = m;
    for (size_t j = O.numFrontals; j < O.vars.size(); ++j) h = std::min(h, scratchPos_[O.vars[j]]);
    O.parent = cliqueAt[h];
    cliques_[O.parent].children.push_back(o);
  }
  roots_.insert(roots_.end(), newRoots_.begin(), newRoots_.end());
}

// 6. Numeric elimination, children before parents (reverse creation order).
void Isam2Backend::eliminateCliques(const Top& top) {
  const int nf = static_cast<int>(top.factors.size());
  for (size_t i = top.created.size(); i-- > 0;) {
    Clique& C = cliques_[top.created[i]];
    for (size_t j = 0; j < C.vars.size(); ++j) localIdx_[C.vars[j]] = static_cast<int>(j);
    for (int attempt = 0;; ++attempt) {
      {
        const size_t n = C.n;
        double* M = C.m.writable(n * n + n);
        for (size_t j = 0; j < n; ++j) std::fill_n(M + j * n + j, n - j, 0.0);  // lower part
        std::fill_n(M + n * n, n, 0.0);
      }
      for (int j = 0; j < C.numFrontals; ++j) {
        const int k = scratchPos_[C.vars[j]];
        for (int h = top.homeStart[k]; h < top.homeStart[k + 1]; ++h)
          if (top.homeRows[h] < nf) linearizeInto(top.factors[top.homeRows[h]], C);
      }
      for (int ch : C.children) accumulateChild(cliques_[ch], C);
      if (attempt > 0) {
        // Singular frontal block (an unconstrained gauge or variable): damp it so the update
        // still completes; the affected directions stay where they were.
        const double lambda = 1e-9 * std::pow(100.0, attempt);
        for (int j = 0; j < C.nf; ++j) {
          double& d = C.m.data()[static_cast<size_t>(j) * C.n + j];
          d += lambda * (1.0 + std::abs(d));
        }
      }
      C.damped = attempt > 0;
      if (factorizeClique(C) || attempt >= 6) break;
    }
    for (int v : C.vars) localIdx_[v] = -1;
  }
}

}  // namespace loopd
