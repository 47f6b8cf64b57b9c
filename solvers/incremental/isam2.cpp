// GCC 12 reports a false -Wmaybe-uninitialized inside Eigen's AVX-512 GEMM packing.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "solvers/incremental/isam2.h"

#include <ccolamd.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <unordered_set>

#include "solvers/backend/update_validation.h"
#include "solvers/batch/nonlinear_optimizer.h"
#include "solvers/factors/prior_factors.h"
#include "solvers/problem/initial_guess.h"

namespace loopd {

namespace {

constexpr FactorId kGaugeFactorId = std::numeric_limits<FactorId>::max();

using MatMap = Eigen::Map<Eigen::MatrixXd, 0, Eigen::OuterStride<>>;
using ConstMatMap = Eigen::Map<const Eigen::MatrixXd, 0, Eigen::OuterStride<>>;

}  // namespace

Isam2Backend::Isam2Backend(BackendOptions options, Isam2Options isam)
    : options_(std::move(options)), isam_(isam) {
  if (isam_.relinearizeSkip < 1) isam_.relinearizeSkip = 1;
}

// ---------------------------------------------------------------------------------------------
// Bookkeeping

int Isam2Backend::addVariable(const Values& from, int slot) {
  const int v = theta_.insertFrom(from, slot);
  estimate_.insertFrom(from, slot);
  dims_.push_back(varDim(theta_.type(v)));
  cliqueOf_.push_back(-1);
  delta_.resize(delta_.size() + kMaxVarDim, 0.0);
  varFactors_.emplace_back();
  affectedStamp_.push_back(-1);
  changedStamp_.push_back(-1);
  relinCandidate_.push_back(0);
  scratchPos_.push_back(-1);
  localIdx_.push_back(-1);
  constrainedStamp_.push_back(-1);
  movedStamp_.push_back(-1);
  touched_.push_back(updateCount_);
  if (firstPose_ < 0 && keyKind(theta_.key(v)) == KeyKind::Pose &&
      (theta_.type(v) == VarType::SE2 || theta_.type(v) == VarType::SE3))
    firstPose_ = v;
  newestVar_ = v;
  return v;
}

void Isam2Backend::markAffected(int v) {
  if (affectedStamp_[v] == epoch_) return;
  affectedStamp_[v] = epoch_;
  affected_.push_back(v);
}

int Isam2Backend::addFactor(const FactorPtr& f) {
  const int index = static_cast<int>(factors_.size());
  factors_.push_back(f);
  std::array<int, kMaxFactorKeys> vars;
  vars.fill(-1);
  for (int k = 0; k < f->size(); ++k) {
    const int v = estimate_.slot(f->key(k));
    vars[k] = v;
    varFactors_[v].push_back(index);
    markAffected(v);
  }
  factorVars_.push_back(vars);
  factorStamp_.push_back(-1);
  return index;
}

void Isam2Backend::removeFactor(int index) {
  const Factor& f = *factors_[index];
  for (int k = 0; k < f.size(); ++k) {
    const int v = factorVars_[index][k];
    auto& list = varFactors_[v];
    list.erase(std::find(list.begin(), list.end(), index));
    markAffected(v);
  }
  factors_[index].reset();
}

void Isam2Backend::manageGauge() {
  if (priorCount_ == 0 && gaugeFactor_ < 0 && firstPose_ >= 0) {
    const int v = firstPose_;
    FactorPtr prior;
    if (estimate_.type(v) == VarType::SE2)
      prior = std::make_shared<PriorFactorSE2>(
          estimate_.key(v), estimate_.se2(v), isam_.gaugeInformation * Eigen::Matrix3d::Identity());
    else
      prior = std::make_shared<PriorFactorSE3>(estimate_.key(v), estimate_.se3(v),
                                               isam_.gaugeInformation * Mat6::Identity());
    std::const_pointer_cast<Factor>(prior)->setId(kGaugeFactorId);
    std::const_pointer_cast<Factor>(prior)->setRole(FactorRole::Prior);
    gaugeFactor_ = addFactor(prior);
  } else if (priorCount_ > 0 && gaugeFactor_ >= 0) {
    removeFactor(gaugeFactor_);
    gaugeFactor_ = -1;
  }
}

double Isam2Backend::deltaMax(int v) const {
  const double* d = &delta_[static_cast<size_t>(v) * kMaxVarDim];
  double m = 0.0;
  for (int i = 0; i < dims_[v]; ++i) m = std::max(m, std::abs(d[i]));
  return m;
}

void Isam2Backend::relinearize(bool all) {
  auto relinearizeVar = [&](int v) {
    // θ ← θ ⊕ Δ is exactly the current estimate; Δ restarts from zero.
    std::memcpy(theta_.data(v), estimate_.data(v), sizeof(double) * kValueStride);
    std::fill_n(&delta_[static_cast<size_t>(v) * kMaxVarDim], kMaxVarDim, 0.0);
    ++stats_.relinearized;
  };
  if (all) {
    for (int v = 0; v < theta_.size(); ++v) {
      relinCandidate_[v] = 0;
      if (varFactors_[v].empty()) continue;
      relinearizeVar(v);
      markAffected(v);
    }
    relinCandidates_.clear();
    return;
  }
  for (int v : relinCandidates_) {
    relinCandidate_[v] = 0;
    if (cliqueOf_[v] < 0 || deltaMax(v) < isam_.relinearizeThreshold) continue;
    relinearizeVar(v);
    // Every factor on v changes its linearization: the cliques holding those factors (the
    // clique of the factor's first-eliminated variable) must be re-eliminated.
    markAffected(v);
    for (int f : varFactors_[v])
      for (int k = 0; k < factors_[f]->size(); ++k) markAffected(factorVars_[f][k]);
  }
  relinCandidates_.clear();
}

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
// Update

UpdateResult Isam2Backend::update(const BackendUpdate& u) {
  const auto t0 = std::chrono::steady_clock::now();
  // Complete the initial values (odometry composition), then validate before any change.
  Values guess = u.initial;
  predictMissingValues(u.factors, estimate_, guess);
  validateUpdate(u, estimate_, idIndex_, guess);

  ++epoch_;
  ++updateCount_;
  stats_ = {};
  affected_.clear();
  UpdateResult result;

  for (int s = 0; s < guess.size(); ++s) {
    const int v = addVariable(guess, s);
    movedStamp_[v] = epoch_;
    result.moved.push_back(estimate_.key(v));
  }
  if (!u.removals.empty()) {
    std::unordered_set<FactorId> removed(u.removals.begin(), u.removals.end());
    for (FactorId id : u.removals) {
      const auto it = idIndex_.find(id);
      if (factors_[it->second]->role() == FactorRole::Prior) --priorCount_;
      removeFactor(it->second);
      idIndex_.erase(it);
    }
    FactorGraph kept;
    kept.reserve(graph_.size());
    for (const auto& f : graph_.factors())
      if (!removed.count(f->id())) kept.add(f);
    graph_ = std::move(kept);
  }
  for (const auto& f : u.factors) {
    const int index = addFactor(f);
    idIndex_[f->id()] = index;
    graph_.add(f);
    if (f->role() == FactorRole::Prior) ++priorCount_;
    for (int k = 0; k < f->size(); ++k) {
      constrainedStamp_[factorVars_[index][k]] = epoch_;
      touched_[factorVars_[index][k]] = updateCount_;
    }
  }
  manageGauge();
  if (relinearizeNext_ || updateCount_ % isam_.relinearizeSkip == 0) relinearize(false);
  relinearizeNext_ = false;
  result.relinearized = stats_.relinearized;

  recompute();
  backSubstitute(&result.moved);

  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

// ---------------------------------------------------------------------------------------------
// Re-elimination of the top

void Isam2Backend::recompute() {
  // 1. The top: cliques holding affected variables, and all their ancestors.
  std::vector<int> topCliques, topVars, orphans;
  auto listVar = [&](int v) {
    if (scratchPos_[v] >= 0 || varFactors_[v].empty()) return;
    scratchPos_[v] = static_cast<int>(topVars.size());
    topVars.push_back(v);
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
      if (cliques_[ch].topStamp != epoch_) orphans.push_back(ch);
  }
  if (!topCliques.empty()) {
    roots_.erase(std::remove_if(roots_.begin(), roots_.end(),
                                [&](int c) { return cliques_[c].topStamp == epoch_; }),
                 roots_.end());
    for (int c : topCliques) freeClique(c);
  }
  for (int o : orphans) cliques_[o].parent = -1;
  newRoots_.clear();
  stats_.topCliques = static_cast<int>(topCliques.size());
  stats_.topVariables = static_cast<int>(topVars.size());
  stats_.orphans = static_cast<int>(orphans.size());
  const int m = static_cast<int>(topVars.size());
  if (m == 0) return;

  // 2. The rows of the top: factors entirely inside it, and the orphans' separator factors.
  std::vector<int> topFactors;
  for (int v : topVars)
    for (int f : varFactors_[v]) {
      if (factorStamp_[f] == epoch_) continue;
      factorStamp_[f] = epoch_;
      bool inside = true;
      for (int k = 0; k < factors_[f]->size() && inside; ++k)
        inside = scratchPos_[factorVars_[f][k]] >= 0;
      if (inside) topFactors.push_back(f);
    }

  // 3. Constrained ordering (CCOLAMD): variables of the new factors last.
  std::vector<int> order(m);
  if (m <= 2) {
    int next = 0;
    for (int pass = 0; pass < 2; ++pass)
      for (int i = 0; i < m; ++i)
        if ((constrainedStamp_[topVars[i]] == epoch_) == (pass == 1)) order[next++] = i;
  } else {
    // The top's rows (its factors and the orphans' separator factors) as lists of columns.
    const int nrow = static_cast<int>(topFactors.size() + orphans.size());
    std::vector<int> rowPtr(nrow + 1, 0), rowCol;
    rowCol.reserve(static_cast<size_t>(nrow) * 3);
    for (int r = 0; r < static_cast<int>(topFactors.size()); ++r) {
      const int f = topFactors[r];
      for (int k = 0; k < factors_[f]->size(); ++k)
        rowCol.push_back(scratchPos_[factorVars_[f][k]]);
      rowPtr[r + 1] = static_cast<int>(rowCol.size());
    }
    for (size_t o = 0; o < orphans.size(); ++o) {
      const Clique& O = cliques_[orphans[o]];
      for (size_t i = O.numFrontals; i < O.vars.size(); ++i)
        rowCol.push_back(scratchPos_[O.vars[i]]);
      rowPtr[topFactors.size() + o + 1] = static_cast<int>(rowCol.size());
    }
    const int nnz = static_cast<int>(rowCol.size());
    std::vector<int> colPtr(m + 1, 0);
    for (int c : rowCol) ++colPtr[c + 1];
    for (int j = 0; j < m; ++j) colPtr[j + 1] += colPtr[j];
    const size_t alen = ccolamd_recommended(nnz, nrow, m);
    std::vector<int> A(alen), p(m + 1);
    // CCOLAMD with constraint groups (null: unconstrained); false if it failed.
    auto runCcolamd = [&](const int* cmember, std::vector<int>& out) {
      std::vector<int> fill(colPtr.begin(), colPtr.end() - 1);
      for (int r = 0; r < nrow; ++r)
        for (int i = rowPtr[r]; i < rowPtr[r + 1]; ++i) A[fill[rowCol[i]]++] = r;
      std::copy(colPtr.begin(), colPtr.end(), p.begin());
      double knobs[CCOLAMD_KNOBS];
      int statsOut[CCOLAMD_STATS];
      ccolamd_set_defaults(knobs);
      if (!ccolamd(nrow, m, static_cast<int>(alen), A.data(), p.data(), knobs, statsOut,
                   const_cast<int*>(cmember)))
        return false;
      out.assign(p.begin(), p.begin() + m);
      return true;
    };
    // Elimination work of an ordering: Σ over variables of dim · (dim of its column)², from
    // a symbolic elimination (a variable's structure: its rows' later variables and its
    // elimination-tree children's).
    auto eliminationCost = [&](const std::vector<int>& ord) {
      std::vector<int> pos(m), home(nrow), homeHead(m, -1), homeNext(nrow, -1);
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
            width += dims_[topVars[ord[q]]];
          }
        };
        for (int r = homeHead[k]; r >= 0; r = homeNext[r])
          for (int i = rowPtr[r]; i < rowPtr[r + 1]; ++i) add(pos[rowCol[i]]);
        for (int c = childHead[k]; c >= 0; c = childNext[c]) {
          for (int q : st[c]) add(q);
          std::vector<int>().swap(st[c]);
        }
        const double d = dims_[topVars[ord[k]]];
        cost += d * (d + width) * (d + width);
        if (first < m) {
          childNext[k] = childHead[first];
          childHead[first] = k;
        }
      }
      return cost;
    };
    // Groups: the variables of the new factors last (they form the new root, so the next
    // update stays small); with recencyGrouping, variables no new factor has touched for
    // that many updates first, so they sink below the part of the tree that updates keep
    // visiting instead of staying on its path to the root — kept only if it costs little
    // more fill than the plain order.
    std::vector<int> cmember(m, 0);
    bool anyConstrained = false, allConstrained = true, anyRecent = false;
    int numOld = 0;
    for (int i = 0; i < m; ++i) {
      const bool c = constrainedStamp_[topVars[i]] == epoch_;
      cmember[i] = c ? 1 : 0;
      anyConstrained |= c;
      allConstrained &= c;
      if (!c) {
        const bool old = updateCount_ - touched_[topVars[i]] > isam_.recencyGrouping;
        if (old)
          ++numOld;
        else
          anyRecent = true;
      }
    }
    const bool twoGroups = anyConstrained && !allConstrained;
    bool ok = runCcolamd(twoGroups ? cmember.data() : nullptr, order);
    // Only where old variables are a sizeable part of the top (a quarter or more): where
    // closures keep returning everywhere (city10000) the constraint buys nothing and its
    // extra fill costs time.
    if (ok && isam_.recencyGrouping > 0 && anyRecent && 4 * numOld >= m) {
      std::vector<int> grouped(m, 0), alt;
      for (int i = 0; i < m; ++i)
        grouped[i] =
            cmember[i] ? 2 : (updateCount_ - touched_[topVars[i]] > isam_.recencyGrouping ? 0 : 1);
      if (!anyConstrained)
        for (int& g : grouped) g = std::min(g, 1);
      if (runCcolamd(grouped.data(), alt) &&
          eliminationCost(alt) <= isam_.recencyFillTolerance * eliminationCost(order))
        order.swap(alt);
    }
    if (!ok)
      for (int k = 0; k < m; ++k) order[k] = k;
  }
  std::vector<int> ov(m);  // variable at each position
  for (int k = 0; k < m; ++k) ov[k] = topVars[order[k]];
  for (int k = 0; k < m; ++k) scratchPos_[ov[k]] = k;

  // 4. Symbolic elimination: each row's home is its first-eliminated variable; the structure
  //    of a variable's column is its rows' later variables plus its etree children's.
  std::vector<int> homeStart(m + 1, 0), homeRows;
  const int nf = static_cast<int>(topFactors.size());
  const int nrows = nf + static_cast<int>(orphans.size());
  std::vector<int> rowHome(nrows);
  for (int r = 0; r < nrows; ++r) {
    int h = m;
    if (r < nf) {
      const int f = topFactors[r];
      for (int k = 0; k < factors_[f]->size(); ++k) h = std::min(h, scratchPos_[factorVars_[f][k]]);
    } else {
      const Clique& O = cliques_[orphans[r - nf]];
      for (size_t i = O.numFrontals; i < O.vars.size(); ++i)
        h = std::min(h, scratchPos_[O.vars[i]]);
    }
    rowHome[r] = h;
    ++homeStart[h + 1];
  }
  for (int k = 0; k < m; ++k) homeStart[k + 1] += homeStart[k];
  homeRows.resize(nrows);
  {
    std::vector<int> fill(homeStart.begin(), homeStart.end() - 1);
    for (int r = 0; r < nrows; ++r) homeRows[fill[rowHome[r]]++] = r;
  }
  std::vector<std::vector<int>> structure(m);
  std::vector<int> etParent(m, -1), childHead(m, -1), childNext(m, -1), mark(m, -1);
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
      if (r < nf) {
        const int f = topFactors[r];
        for (int j = 0; j < factors_[f]->size(); ++j) add(scratchPos_[factorVars_[f][j]]);
      } else {
        const Clique& O = cliques_[orphans[r - nf]];
        for (size_t j = O.numFrontals; j < O.vars.size(); ++j) add(scratchPos_[O.vars[j]]);
      }
    }
    for (int c = childHead[k]; c >= 0; c = childNext[c])
      for (int q : structure[c]) add(q);
    std::sort(s.begin(), s.end());
    if (!s.empty()) {
      etParent[k] = s.front();
      childNext[k] = childHead[s.front()];
      childHead[s.front()] = k;
    }
  }

  // 5. Cliques, from the root down: a variable joins its parent's clique when its structure
  //    is exactly that clique's variables.
  std::vector<int> cliqueAt(m, -1), created;
  std::vector<int> firstFrontal;  // per created clique (index in `created`)
  // clique id → index in created: a member kept all −1 between updates (a per-update vector
  // the size of the tree would cost O(n) per update).
  std::vector<int>& createdIndex = createdIndex_;
  for (int k = m - 1; k >= 0; --k) {
    const int p = etParent[k];
    if (p >= 0) {
      const int C = cliqueAt[p];
      const int ci = createdIndex[C];
      if (firstFrontal[ci] == p && structure[k].size() == structure[p].size() + 1) {
        cliques_[C].vars.push_back(ov[k]);  // frontals collected last-eliminated first
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
    C.vars.push_back(ov[k]);
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
    for (int q : structure[last]) C.vars.push_back(ov[q]);
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
  for (int o : orphans) {
    Clique& O = cliques_[o];
    int h = m;
    for (size_t j = O.numFrontals; j < O.vars.size(); ++j) h = std::min(h, scratchPos_[O.vars[j]]);
    O.parent = cliqueAt[h];
    cliques_[O.parent].children.push_back(o);
  }
  roots_.insert(roots_.end(), newRoots_.begin(), newRoots_.end());

  // 6. Numeric elimination, children before parents (reverse creation order).
  for (size_t i = created.size(); i-- > 0;) {
    Clique& C = cliques_[created[i]];
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
        for (int h = homeStart[k]; h < homeStart[k + 1]; ++h)
          if (homeRows[h] < nf) linearizeInto(topFactors[homeRows[h]], C);
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
      if (factorizeClique(C) || attempt >= 6) break;
    }
    for (int v : C.vars) localIdx_[v] = -1;
  }
  for (int v : topVars) scratchPos_[v] = -1;
}

namespace {

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

// ---------------------------------------------------------------------------------------------
// Converging: full relinearization until the cost stops decreasing

void Isam2Backend::relinearizeAllAtEstimate() {
  ++epoch_;
  stats_ = {};
  affected_.clear();
  relinearize(true);
  if (newestVar_ >= 0) constrainedStamp_[newestVar_] = epoch_;
  recompute();
}

void Isam2Backend::resetEstimate(const Values& x) {
  for (int v = 0; v < estimate_.size(); ++v) {
    const int s = x.slot(estimate_.key(v));
    if (s >= 0) std::memcpy(estimate_.data(v), x.data(s), sizeof(double) * kValueStride);
  }
  relinearizeAllAtEstimate();
}

void Isam2Backend::optimize() {
  if (factors_.empty()) return;
  auto cost = [&]() {
    double c = graph_.chi2(estimate_);
    if (gaugeFactor_ >= 0) c += factors_[gaugeFactor_]->chi2(estimate_);
    return c;
  };
  auto fullStep = [&]() {
    relinearizeAllAtEstimate();
    backSubstitute(nullptr);
  };
  auto revert = [&]() {  // back to θ (the estimate before the last step)
    ++epoch_;
    for (int v = 0; v < theta_.size(); ++v) {
      std::memcpy(estimate_.data(v), theta_.data(v), sizeof(double) * kValueStride);
      std::fill_n(&delta_[static_cast<size_t>(v) * kMaxVarDim], kMaxVarDim, 0.0);
    }
  };
  summary_ = {};
  summary_.initialChi2 = graph_.chi2(estimate_);
  double previous = cost();
  int iterations = 0;
  bool converged = false, usedBatch = false;
  for (int round = 0; round < 2 && !converged; ++round) {
    for (int it = 0; it < isam_.maxFinalIterations; ++it) {
      fullStep();
      ++iterations;
      const double current = cost();
      if (!(current <= previous * (1.0 + 1e-9) + 1e-12)) {
        revert();
        break;
      }
      const double gain = previous - current;
      previous = current;
      if (gain <= isam_.finalRelativeTolerance * current + 1e-14) {
        converged = true;
        break;
      }
    }
    if (converged || round == 1) break;
    // Gauss–Newton went uphill: Levenberg–Marquardt on the whole graph, then rebuild.
    usedBatch = true;
    FactorGraph all = graph_;
    if (gaugeFactor_ >= 0) all.add(factors_[gaugeFactor_]);
    std::vector<char> fixed(estimate_.size(), 0);
    for (int v = 0; v < estimate_.size(); ++v) fixed[v] = varFactors_[v].empty() ? 1 : 0;
    OptimizerOptions o;
    o.method = OptimizerMethod::LevenbergMarquardt;
    o.maxIterations = std::max(options_.maxIterations, 100);
    NonlinearOptimizer lm(all, estimate_, fixed, o);
    const OptimizerResult r = lm.optimize(estimate_);
    iterations += r.iterations;
    previous = cost();
  }
  if (!converged) {
    // Leave the tree linearized at the final estimate without taking another step.
    ++epoch_;
    affected_.clear();
    relinearize(true);
    recompute();
  }
  summary_.iterations = iterations;
  summary_.finalChi2 = graph_.chi2(estimate_);
  summary_.converged = converged;
  summary_.stopReason =
      converged ? (usedBatch ? "converged (after batch LM)" : "converged") : "iteration limit";
}

}  // namespace loopd
