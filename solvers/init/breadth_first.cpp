#include "solvers/init/breadth_first.h"

#include <cstddef>
#include <deque>

namespace loopd {

std::vector<int> breadthFirstOrder(const std::vector<std::vector<int>>& adjacency, int anchor) {
  std::vector<int> order;
  std::vector<char> seen(adjacency.size(), 0);
  std::deque<int> queue{anchor};
  seen[static_cast<std::size_t>(anchor)] = 1;
  while (!queue.empty()) {
    const int s = queue.front();
    queue.pop_front();
    order.push_back(s);
    for (int t : adjacency[static_cast<std::size_t>(s)])
      if (!seen[static_cast<std::size_t>(t)]) {
        seen[static_cast<std::size_t>(t)] = 1;
        queue.push_back(t);
      }
  }
  return order;
}

}  // namespace loopd
