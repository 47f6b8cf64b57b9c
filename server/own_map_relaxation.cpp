#include "server/own_map_relaxation.h"

#include "robust/robust_factors.h"
#include "solvers/batch/nonlinear_optimizer.h"
#include "solvers/graph/connected_parts.h"
#include "solvers/graph/factor_graph.h"

namespace loopd::server {

void relaxOwnMaps(const std::vector<FactorPtr>& factors, Values& poses, int maxIterations) {
  FactorGraph graph;
  ConnectedParts parts(poses.size());
  for (const FactorPtr& f : factors) {
    const int a = poses.slot(f->key(0)), b = poses.slot(f->key(1));
    if (a < 0 || b < 0) continue;
    graph.add(f);
    parts.join(a, b);
  }
  if (graph.empty()) return;
  // The gauge: the lowest key of each connected part is held where it is.
  std::vector<int> lowest(static_cast<size_t>(poses.size()), -1);
  for (int s = 0; s < poses.size(); ++s) {
    int& l = lowest[parts.part(s)];
    if (l < 0 || poses.key(s) < poses.key(l)) l = s;
  }
  std::vector<char> fixed(lowest.size(), 0);
  for (int l : lowest)
    if (l >= 0) fixed[l] = 1;
  OptimizerOptions options;
  options.maxIterations = maxIterations;
  Values relaxed = poses;
  try {
    NonlinearOptimizer lm(graph, relaxed, fixed, options);
    lm.optimize(relaxed);
  } catch (const std::exception&) {
    return;
  }
  if (relaxed.allFinite()) poses.assignFrom(relaxed);
}

std::vector<FactorPtr> closuresThatFit(const std::vector<FactorPtr>& closures,
                                       const Values& poses) {
  std::vector<FactorPtr> fit;
  for (const FactorPtr& f : closures) {
    bool known = true;
    for (int k = 0; known && k < f->size(); ++k) known = poses.contains(f->key(k));
    if (known && f->chi2(poses) < chi2Quantile(f->dim(), kFitProbability)) fit.push_back(f);
  }
  return fit;
}

}  // namespace loopd::server
