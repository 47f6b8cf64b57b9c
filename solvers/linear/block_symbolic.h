#pragma once
// Symbolic analysis for BlockCholesky: from the block pattern of H (upper-triangle scalar CSC
// whose variables are contiguous scalar blocks, already in a fill-reducing order) it builds the
// block elimination tree, postorders it (same fill, longer chains), finds fundamental block
// supernodes, amalgamates them (relaxed, CHOLMOD's rules, counted in scalar columns) and lays
// out one dense column-major panel per supernode. Everything factorize/solve need is computed
// here once: panel offsets, scalar row lists, and the map from each CSC value to its slot in L.
#include <vector>

namespace loopd {

struct BlockSymbolic {
  int n = 0;          // scalar dimension
  int numBlocks = 0;  // variables
  int numSupernodes = 0;

  /// Postorder of the block elimination tree: permuted scalar k holds original scalar
  /// scalarPerm[k]. identity is true when the postorder kept the given order.
  std::vector<int> scalarPerm;
  bool identity = true;
  /// The permutation as disjoint cycles (for applying it in place, without workspace):
  /// cycleStart has one entry per cycle plus the end; cycles lists scalar indices.
  std::vector<int> cycleStart, cycles;

  /// Supernode s covers permuted scalar columns [superCol[s], superCol[s+1]); its panel has
  /// rows rows[rowStart[s] .. rowStart[s+1]) (own columns first, then the rows below, all
  /// increasing) and is stored column-major at valueStart[s] with leading dimension = rows.
  std::vector<int> superCol;
  std::vector<int> rowStart;
  std::vector<int> rows;
  std::vector<long> valueStart;
  std::vector<int> superOfCol;  // permuted scalar column → supernode

  /// CSC value k of H goes to L[valueMap[k]] (−1: strictly lower entry of a diagonal block,
  /// ignored).
  std::vector<int> valueMap;

  long factorNonZeros = 0;  // scalar nnz of the true L (without amalgamation zeros)
  long panelEntries = 0;    // stored panel entries (with amalgamation zeros, whole rectangles)
  double flops = 0.0;       // Σ over columns of (count incl. diagonal)², as CHOLMOD reports
  long maxUpdate = 0;       // largest descendant-update workspace needed (doubles)
  int maxRows = 0;          // largest panel row count
};

/// Throws std::invalid_argument if the arrays are inconsistent (sizes, empty blocks, rows out of
/// range or below their column's diagonal block). Any block size works; the numeric kernels
/// are tuned for 1..6.
void analyzeBlockPattern(const std::vector<int>& blockOffsets, const std::vector<int>& columnStart,
                         const std::vector<int>& rowIndex, BlockSymbolic& out);

}  // namespace loopd
