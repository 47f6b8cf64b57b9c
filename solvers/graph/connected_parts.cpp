#include "solvers/graph/connected_parts.h"

#include <cstddef>
#include <numeric>

namespace loopd {

ConnectedParts::ConnectedParts(int n) : parent_(static_cast<std::size_t>(n)) {
  std::iota(parent_.begin(), parent_.end(), 0);
}

void ConnectedParts::join(int a, int b) { parent_[part(a)] = part(b); }

int ConnectedParts::part(int s) {
  while (parent_[s] != s) s = parent_[s] = parent_[parent_[s]];
  return s;
}

}  // namespace loopd
