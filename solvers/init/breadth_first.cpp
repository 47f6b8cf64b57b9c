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

ReachableUnknowns numberReachable(const FactorGraph& graph, const Values& values, int anchorSlot,
                                  const std::function<bool(const Factor&)>& joins,
                                  const std::function<int(int)>& dims) {
  std::vector<std::vector<int>> adjacency(static_cast<std::size_t>(values.size()));
  for (const auto& f : graph.factors()) {
    if (f->size() != 2 || !joins(*f)) continue;
    const int a = values.slot(f->key(0)), b = values.slot(f->key(1));
    if (a < 0 || b < 0) continue;
    adjacency[static_cast<std::size_t>(a)].push_back(b);
    adjacency[static_cast<std::size_t>(b)].push_back(a);
  }
  ReachableUnknowns u;
  u.index.assign(static_cast<std::size_t>(values.size()), -1);
  for (int s : breadthFirstOrder(adjacency, anchorSlot))
    if (s != anchorSlot) {
      u.index[static_cast<std::size_t>(s)] = u.count;
      u.count += dims(s);
    }
  return u;
}

}  // namespace loopd
