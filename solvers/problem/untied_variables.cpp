#include "solvers/problem/untied_variables.h"

#include "solvers/graph/connected_parts.h"

namespace loopd {

std::vector<Key> untiedVariables(const FactorGraph& graph, const Values& values, Key gauge) {
  ConnectedParts parts(values.size());
  std::vector<int> anchored;  // slots the world places: the gauge, and every prior's variable
  if (values.slot(gauge) >= 0) anchored.push_back(values.slot(gauge));
  for (const FactorPtr& f : graph.factors()) {
    int first = -1;
    for (int k = 0; k < f->size(); ++k) {
      const int s = values.slot(f->key(k));
      if (s < 0) continue;
      if (first < 0)
        first = s;
      else
        parts.join(first, s);
    }
    if (f->size() == 1 && first >= 0) anchored.push_back(first);
  }
  std::vector<char> tied(static_cast<size_t>(values.size()), 0);
  for (int s : anchored) tied[parts.part(s)] = 1;
  std::vector<Key> untied;
  for (int s = 0; s < values.size(); ++s)
    if (!tied[parts.part(s)]) untied.push_back(values.key(s));
  return untied;
}

}  // namespace loopd
