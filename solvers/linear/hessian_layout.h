#pragma once
// The sparsity pattern of the Gauss–Newton Hessian H = JᵀJ over a fixed factor graph, built
// once: variables are laid out in a fill-reducing block order (AMD on the variable graph), so
// CHOLMOD factors H in its natural order; every factor knows where each of its Jacobian
// products lands in H's upper-triangle CSC arrays, so assembly is pure arithmetic.
#include <vector>

#include "solvers/graph/factor_graph.h"

namespace loopd {

class HessianLayout {
 public:
  /// fixedSlots[s] true: variable s is held constant (gauge) and has no columns.
  /// activeFactors (empty: all): factors whose products have a place in H; the others' keys
  /// are still resolved (their χ² can be evaluated) but they add no entries, so they must be
  /// built with weight 0.
  /// Throws std::invalid_argument if a factor refers to a key missing from values.
  HessianLayout(const FactorGraph& graph, const Values& values, const std::vector<char>& fixedSlots,
                const std::vector<char>& activeFactors = {});

  int dimension() const { return dimension_; }  // scalar unknowns
  long nonZeros() const { return static_cast<long>(rowIndex_.size()); }
  const std::vector<int>& columnStart() const { return columnStart_; }  // n+1 entries
  const std::vector<int>& rowIndex() const { return rowIndex_; }
  /// Scalar offset of each Values slot, −1 for fixed variables.
  const std::vector<int>& slotOffset() const { return slotOffset_; }
  /// Scalar offsets of the active variables in elimination order, plus dimension() at the
  /// end: variable b occupies [blockOffsets[b], blockOffsets[b+1]).
  const std::vector<int>& blockOffsets() const { return blockOffsets_; }
  /// Values slot of each factor key (factor-major, kMaxFactorKeys each).
  int factorSlot(int factor, int k) const { return factorSlots_[factor * kMaxFactorKeys + k]; }
  /// Position in the CSC value array of entry (0, 0) of block (key a, key b) of factor f,
  /// for a and b with slotOffset(a) ≤ slotOffset(b); −1 if either is fixed.
  int blockStart(int factor, int a, int b) const {
    return blockStart_[factor * kPairs + a * kMaxFactorKeys + b];
  }
  /// Entries per column of a slot's variable (all its columns have the same length, since
  /// diagonal blocks are stored whole; CHOLMOD ignores their lower part).
  int columnLength(int slot) const { return columnLength_[slot]; }
  /// Whether factor f has a place in H (see the constructor).
  bool isActive(int f) const { return activeFactors_.empty() || activeFactors_[f]; }
  /// Positions of the diagonal entries of H in the CSC value array.
  const std::vector<int>& diagonalPositions() const { return diagonal_; }

 private:
  static constexpr int kPairs = kMaxFactorKeys * kMaxFactorKeys;
  int dimension_ = 0;
  std::vector<int> slotOffset_;
  std::vector<int> factorSlots_;
  std::vector<int> columnStart_;
  std::vector<int> rowIndex_;
  std::vector<int> blockStart_;
  std::vector<int> diagonal_;
  std::vector<int> columnLength_;
  std::vector<int> blockOffsets_;
  std::vector<char> activeFactors_;
};

}  // namespace loopd
