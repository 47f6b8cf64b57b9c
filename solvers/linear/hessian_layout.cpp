#include "solvers/linear/hessian_layout.h"

#include <amd.h>

#include <algorithm>
#include <stdexcept>

namespace loopd {

namespace {

// Fill-reducing order of the active variables from AMD on the variable adjacency graph.
std::vector<int> blockOrdering(int n, const std::vector<std::vector<int>>& adjacency) {
  std::vector<int> Ap(n + 1, 0), Ai;
  for (int v = 0; v < n; ++v) {
    Ap[v + 1] = Ap[v] + static_cast<int>(adjacency[v].size());
    Ai.insert(Ai.end(), adjacency[v].begin(), adjacency[v].end());
  }
  std::vector<int> perm(n);
  if (n == 0) return perm;
  if (Ai.empty()) Ai.push_back(0);  // amd needs a valid pointer
  const int status = amd_order(n, Ap.data(), Ai.data(), perm.data(), nullptr, nullptr);
  if (status < AMD_OK) throw std::runtime_error("AMD ordering failed");
  return perm;
}

}  // namespace

HessianLayout::HessianLayout(const FactorGraph& graph, const Values& values,
                             const std::vector<char>& fixedSlots,
                             const std::vector<char>& activeFactors)
    : activeFactors_(activeFactors) {
  const int numSlots = values.size();
  const int numFactors = graph.size();
  if (!activeFactors.empty() && static_cast<int>(activeFactors.size()) != numFactors)
    throw std::invalid_argument("HessianLayout: one active flag per factor expected");

  // Resolve keys to slots and number the active (non-fixed) variables.
  factorSlots_.assign(static_cast<size_t>(numFactors) * kMaxFactorKeys, -1);
  std::vector<int> active(numSlots, -1), activeSlot;
  for (int s = 0; s < numSlots; ++s)
    if (fixedSlots.empty() || !fixedSlots[s]) {
      active[s] = static_cast<int>(activeSlot.size());
      activeSlot.push_back(s);
    }
  const int n = static_cast<int>(activeSlot.size());
  std::vector<std::vector<int>> adjacency(n);
  for (int f = 0; f < numFactors; ++f) {
    const Factor& factor = *graph[f];
    for (int k = 0; k < factor.size(); ++k) {
      const int s = values.slot(factor.key(k));
      if (s < 0)
        throw std::invalid_argument("factor " + std::to_string(f) + " refers to missing " +
                                    keyToString(factor.key(k)));
      if (values.type(s) != factor.varType(k))
        throw std::invalid_argument("factor " + std::to_string(f) + " expects " +
                                    varTypeName(factor.varType(k)) + " for " +
                                    keyToString(factor.key(k)));
      factorSlots_[f * kMaxFactorKeys + k] = s;
    }
    if (!activeFactors.empty() && !activeFactors[f]) continue;
    for (int a = 0; a < factor.size(); ++a)
      for (int b = 0; b < factor.size(); ++b) {
        const int va = active[factorSlots_[f * kMaxFactorKeys + a]];
        const int vb = active[factorSlots_[f * kMaxFactorKeys + b]];
        if (va >= 0 && vb >= 0 && va != vb) adjacency[va].push_back(vb);
      }
  }
  for (auto& adj : adjacency) {
    std::sort(adj.begin(), adj.end());
    adj.erase(std::unique(adj.begin(), adj.end()), adj.end());
  }

  // Lay variables out in elimination order.
  const std::vector<int> order = blockOrdering(n, adjacency);
  std::vector<int> position(n);
  for (int p = 0; p < n; ++p) position[order[p]] = p;
  slotOffset_.assign(numSlots, -1);
  dimension_ = 0;
  for (int p = 0; p < n; ++p) {
    const int s = activeSlot[order[p]];
    slotOffset_[s] = dimension_;
    blockOffsets_.push_back(dimension_);
    dimension_ += varDim(values.type(s));
  }
  blockOffsets_.push_back(dimension_);

  // Column pattern of each variable: its earlier neighbours, then itself (whole block).
  columnLength_.assign(numSlots, 0);
  columnStart_.assign(dimension_ + 1, 0);
  rowIndex_.clear();
  diagonal_.assign(dimension_, 0);
  // rowPosition[v] maps neighbour u → row position of u's rows within v's columns.
  std::vector<std::vector<std::pair<int, int>>> rowPosition(n);
  for (int p = 0; p < n; ++p) {
    const int v = order[p];
    const int s = activeSlot[v];
    std::vector<int> earlier;
    for (int u : adjacency[v])
      if (position[u] < p) earlier.push_back(u);
    std::sort(earlier.begin(), earlier.end(),
              [&](int x, int y) { return position[x] < position[y]; });
    earlier.push_back(v);
    int len = 0;
    for (int u : earlier) {
      rowPosition[v].emplace_back(u, len);
      len += varDim(values.type(activeSlot[u]));
    }
    columnLength_[s] = len;
    const int dim = varDim(values.type(s));
    const int off = slotOffset_[s];
    for (int c = 0; c < dim; ++c) {
      columnStart_[off + c] = static_cast<int>(rowIndex_.size());
      for (int u : earlier) {
        const int uo = slotOffset_[activeSlot[u]];
        const int ud = varDim(values.type(activeSlot[u]));
        for (int r = 0; r < ud; ++r) rowIndex_.push_back(uo + r);
      }
      diagonal_[off + c] = columnStart_[off + c] + (len - dim) + c;
    }
  }
  columnStart_[dimension_] = static_cast<int>(rowIndex_.size());
  for (auto& rp : rowPosition) std::sort(rp.begin(), rp.end());

  // Where each factor's block products land.
  blockStart_.assign(static_cast<size_t>(numFactors) * kPairs, -1);
  for (int f = 0; f < numFactors; ++f) {
    if (!activeFactors.empty() && !activeFactors[f]) continue;
    const int nk = graph[f]->size();
    for (int a = 0; a < nk; ++a)
      for (int b = 0; b < nk; ++b) {
        const int sa = factorSlots_[f * kMaxFactorKeys + a];
        const int sb = factorSlots_[f * kMaxFactorKeys + b];
        const int va = active[sa], vb = active[sb];
        if (va < 0 || vb < 0 || slotOffset_[sa] > slotOffset_[sb]) continue;
        const auto& rp = rowPosition[vb];
        auto it = std::lower_bound(rp.begin(), rp.end(), std::make_pair(va, -1));
        blockStart_[f * kPairs + a * kMaxFactorKeys + b] =
            columnStart_[slotOffset_[sb]] + it->second;
      }
  }
}

}  // namespace loopd
