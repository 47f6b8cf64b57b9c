#include "solvers/linear/block_symbolic.h"

#include <algorithm>
#include <stdexcept>
#include <string>

namespace loopd {

namespace {

// CHOLMOD's default relaxed-amalgamation rules (cholmod_common nrelax / zrelax), in scalar
// columns: merge a child supernode into its parent when the result is narrow or the fraction
// of explicit zeros it introduces stays small.
bool relaxedMerge(long ncols, double zeroFraction) {
  if (ncols <= 4) return true;
  if (ncols <= 16 && zeroFraction < 0.8) return true;
  if (ncols <= 48 && zeroFraction < 0.1) return true;
  return zeroFraction < 0.05;
}

}  // namespace

void analyzeBlockPattern(const std::vector<int>& blockOffsets, const std::vector<int>& columnStart,
                         const std::vector<int>& rowIndex, BlockSymbolic& out) {
  out = BlockSymbolic{};
  if (blockOffsets.empty() || blockOffsets.front() != 0)
    throw std::invalid_argument("BlockCholesky: blockOffsets must start at 0");
  const int nb = static_cast<int>(blockOffsets.size()) - 1;
  for (int b = 0; b < nb; ++b)
    if (blockOffsets[b + 1] <= blockOffsets[b])
      throw std::invalid_argument("BlockCholesky: empty or decreasing block " + std::to_string(b));
  const int n = blockOffsets.back();
  if (static_cast<int>(columnStart.size()) != n + 1 || columnStart[0] != 0 ||
      columnStart[n] != static_cast<int>(rowIndex.size()))
    throw std::invalid_argument("BlockCholesky: columnStart inconsistent with n / rowIndex");
  for (int c = 0; c < n; ++c)
    if (columnStart[c + 1] < columnStart[c])
      throw std::invalid_argument("BlockCholesky: columnStart decreasing");
  out.n = n;
  out.numBlocks = nb;

  std::vector<int> blockOf(n);
  for (int b = 0; b < nb; ++b)
    for (int c = blockOffsets[b]; c < blockOffsets[b + 1]; ++c) blockOf[c] = b;

  // Upper block pattern: neighbours i < j of every block column j (union over its columns).
  std::vector<std::vector<int>> upper(nb);
  std::vector<int> mark(nb, -1);
  for (int j = 0; j < nb; ++j)
    for (int c = blockOffsets[j]; c < blockOffsets[j + 1]; ++c)
      for (int k = columnStart[c]; k < columnStart[c + 1]; ++k) {
        const int r = rowIndex[k];
        if (r < 0 || r >= n) throw std::invalid_argument("BlockCholesky: row index out of range");
        const int i = blockOf[r];
        if (i > j) throw std::invalid_argument("BlockCholesky: entry below the diagonal block");
        if (i < j && mark[i] != j) {
          mark[i] = j;
          upper[j].push_back(i);
        }
      }

  // Block elimination tree (Liu, with path compression).
  std::vector<int> parent(nb, -1), ancestor(nb, -1);
  for (int j = 0; j < nb; ++j)
    for (int i0 : upper[j])
      for (int i = i0; i != -1 && i < j;) {
        const int next = ancestor[i];
        ancestor[i] = j;
        if (next == -1) parent[i] = j;
        i = next;
      }

  // Postorder (children in increasing order): keeps the fill, makes chains consecutive.
  std::vector<int> post;
  post.reserve(nb);
  {
    std::vector<int> head(nb, -1), next(nb, -1), stack;
    for (int j = nb - 1; j >= 0; --j)
      if (parent[j] != -1) {
        next[j] = head[parent[j]];
        head[parent[j]] = j;
      }
    for (int root = 0; root < nb; ++root) {
      if (parent[root] != -1) continue;
      stack.push_back(root);
      while (!stack.empty()) {
        const int p = stack.back();
        const int child = head[p];
        if (child == -1) {
          stack.pop_back();
          post.push_back(p);
        } else {
          head[p] = next[child];
          stack.push_back(child);
        }
      }
    }
  }
  std::vector<int> newOf(nb), pparent(nb, -1), size(nb), offset(nb + 1, 0);
  for (int k = 0; k < nb; ++k) newOf[post[k]] = k;
  for (int k = 0; k < nb; ++k) {
    const int old = post[k];
    pparent[k] = parent[old] == -1 ? -1 : newOf[parent[old]];
    size[k] = blockOffsets[old + 1] - blockOffsets[old];
    offset[k + 1] = offset[k] + size[k];
  }
  out.scalarPerm.resize(n);
  for (int k = 0; k < nb; ++k)
    for (int t = 0; t < size[k]; ++t) out.scalarPerm[offset[k] + t] = blockOffsets[post[k]] + t;
  out.identity = true;
  for (int k = 0; k < n; ++k)
    if (out.scalarPerm[k] != k) out.identity = false;
  {
    std::vector<char> seen(n, 0);
    out.cycleStart.push_back(0);
    for (int k = 0; k < n; ++k) {
      if (seen[k] || out.scalarPerm[k] == k) continue;
      for (int c = k; !seen[c]; c = out.scalarPerm[c]) {
        seen[c] = 1;
        out.cycles.push_back(c);
      }
      out.cycleStart.push_back(static_cast<int>(out.cycles.size()));
    }
  }

  // Block column structure of L (rows strictly below the diagonal block), permuted order.
  std::vector<std::vector<int>> lowerAdj(nb), children(nb), structure(nb);
  for (int j = 0; j < nb; ++j)
    for (int i : upper[j]) lowerAdj[newOf[i]].push_back(newOf[j]);
  for (int k = 0; k < nb; ++k)
    if (pparent[k] != -1) children[pparent[k]].push_back(k);
  std::fill(mark.begin(), mark.end(), -1);
  std::vector<int> scalarCount(nb, 0);
  for (int k = 0; k < nb; ++k) {
    auto& s = structure[k];
    mark[k] = k;
    for (int j : lowerAdj[k])
      if (mark[j] != k) {
        mark[j] = k;
        s.push_back(j);
      }
    for (int c : children[k])
      for (int j : structure[c])
        if (mark[j] != k) {
          mark[j] = k;
          s.push_back(j);
        }
    std::sort(s.begin(), s.end());
    for (int j : s) scalarCount[k] += size[j];
    for (int t = 0; t < size[k]; ++t) {
      const long count = (size[k] - t) + scalarCount[k];
      out.factorNonZeros += count;
      out.flops += static_cast<double>(count) * static_cast<double>(count);
    }
  }

  // Fundamental block supernodes: a chain k → k+1 with k+1's structure that of k minus k+1.
  std::vector<int> fstart;
  for (int k = 0; k < nb; ++k) {
    const bool extend = k > 0 && pparent[k - 1] == k && children[k].size() == 1 &&
                        structure[k - 1].size() == structure[k].size() + 1;
    if (!extend) fstart.push_back(k);
  }
  const int nf = static_cast<int>(fstart.size());
  fstart.push_back(nb);

  // Relaxed amalgamation: merge supernode f into f+1 when f+1 is its parent.
  std::vector<long> gcols(nf), grows(nf), gnnz(nf);
  std::vector<int> gend(nf);
  std::vector<char> head(nf, 1);
  for (int f = 0; f < nf; ++f) {
    const int top = fstart[f + 1] - 1;
    gcols[f] = offset[fstart[f + 1]] - offset[fstart[f]];
    grows[f] = gcols[f] + scalarCount[top];
    gnnz[f] = gcols[f] * grows[f] - gcols[f] * (gcols[f] - 1) / 2;
    gend[f] = f + 1;
  }
  for (int f = nf - 2; f >= 0; --f) {
    const int top = fstart[f + 1] - 1;
    if (pparent[top] != top + 1) continue;
    const long nc = gcols[f] + gcols[f + 1];
    const long nr = gcols[f] + grows[f + 1];
    const long area = nc * nr - nc * (nc - 1) / 2;
    const long nnz = gnnz[f] + gnnz[f + 1];
    if (!relaxedMerge(nc, static_cast<double>(area - nnz) / static_cast<double>(area))) continue;
    gcols[f] = nc;
    grows[f] = nr;
    gnnz[f] = nnz;
    gend[f] = gend[f + 1];
    head[f + 1] = 0;
  }

  // Lay out the supernodes.
  out.superCol.push_back(0);
  out.rowStart.push_back(0);
  out.valueStart.push_back(0);
  out.superOfCol.assign(n, -1);
  for (int f = 0; f < nf; ++f) {
    if (!head[f]) continue;
    const int b0 = fstart[f], b1 = fstart[gend[f]];
    const int c0 = offset[b0], c1 = offset[b1];
    const int s = static_cast<int>(out.superCol.size()) - 1;
    for (int c = c0; c < c1; ++c) {
      out.rows.push_back(c);
      out.superOfCol[c] = s;
    }
    for (int j : structure[b1 - 1])
      for (int t = 0; t < size[j]; ++t) out.rows.push_back(offset[j] + t);
    const long nr = static_cast<long>(out.rows.size()) - out.rowStart.back();
    out.superCol.push_back(c1);
    out.rowStart.push_back(static_cast<int>(out.rows.size()));
    out.valueStart.push_back(out.valueStart.back() + nr * (c1 - c0));
    out.maxRows = std::max(out.maxRows, static_cast<int>(nr));
  }
  out.numSupernodes = static_cast<int>(out.superCol.size()) - 1;
  out.panelEntries = out.valueStart.back();
  if (out.panelEntries > 2147483647L)
    throw std::invalid_argument("BlockCholesky: factor too large for 32-bit value maps");

  // Largest descendant update: rows of d from the first row of a target to the end, times the
  // rows that fall in that target.
  for (int s = 0; s < out.numSupernodes; ++s) {
    const int* r = out.rows.data() + out.rowStart[s];
    const int nr = out.rowStart[s + 1] - out.rowStart[s];
    int p = out.superCol[s + 1] - out.superCol[s];
    while (p < nr) {
      const int t = out.superOfCol[r[p]];
      int q = p;
      while (q < nr && r[q] < out.superCol[t + 1]) ++q;
      out.maxUpdate = std::max(out.maxUpdate, static_cast<long>(nr - p) * (q - p));
      p = q;
    }
  }

  // Where each CSC value lands: upper entry (row i, column j) of H is L(j, i).
  out.valueMap.assign(rowIndex.size(), -1);
  auto target = [&](int row, int col) -> int {
    const int s = out.superOfCol[col];
    const int* r0 = out.rows.data() + out.rowStart[s];
    const int* r1 = out.rows.data() + out.rowStart[s + 1];
    const int* it = std::lower_bound(r0, r1, row);
    if (it == r1 || *it != row) throw std::logic_error("BlockCholesky: entry outside L's pattern");
    return static_cast<int>(out.valueStart[s] +
                            static_cast<long>(col - out.superCol[s]) * (r1 - r0) + (it - r0));
  };
  for (int j = 0; j < nb; ++j) {
    const int J = newOf[j];
    for (int c = blockOffsets[j]; c < blockOffsets[j + 1]; ++c) {
      const int cj = c - blockOffsets[j];
      for (int k = columnStart[c]; k < columnStart[c + 1]; ++k) {
        const int r = rowIndex[k];
        const int i = blockOf[r];
        const int ri = r - blockOffsets[i];
        if (i == j && ri > cj) continue;  // lower half of the diagonal block: ignored
        out.valueMap[k] = target(offset[J] + cj, offset[newOf[i]] + ri);
      }
    }
  }
}

}  // namespace loopd
