#include "solvers/graph/factor_graph.h"

namespace loopd {

double FactorGraph::chi2(const Values& values) const {
  double sum = 0.0;
  for (const auto& f : factors_) sum += f->chi2(values);
  return sum;
}

double FactorGraph::objective(const Values& values) const {
  double sum = 0.0;
  for (const auto& f : factors_) sum += f->objectiveAt(values);
  return sum;
}

}  // namespace loopd
