#include "server/closure_agreement.h"

#include <algorithm>

#include "robust/pairwise_consistency.h"
#include "solvers/graph/factor_graph.h"

namespace loopd::server {

std::vector<size_t> agreeingClosures(const std::vector<FactorPtr>& closures,
                                     const std::vector<FactorPtr>& odometry, const Values& poses,
                                     double probability, double closureScale) {
  FactorGraph graph;
  for (const FactorPtr& f : odometry) graph.add(f);
  const int first = graph.size();
  for (const FactorPtr& f : closures) graph.add(f);  // PCM judges them from the lower robot
  ConsistencyOptions options;
  options.probability = probability;
  // Each robot's map is taken as exact between the closures' ends: two closures agree when
  // they place the frames within their own noise. The odometry's drift, added, made the test
  // so wide over long chains that two random wrong closures agreed (intel: σ_θ 0.067 rad per
  // step stated); true closures of one revisit still agree without it. The short-cycle
  // calibration only ever narrows the test, and it has too few pairs here to act.
  options.odometryScale = 0.0;
  options.calibrationWindow = 0;
  options.closureScale = closureScale;
  const ConsistentSet set = pairwiseConsistentClosures(graph, poses, options);
  std::vector<size_t> out;
  for (size_t i = 0; i < closures.size(); ++i)
    if (set.member[static_cast<size_t>(first) + i]) out.push_back(i);
  return out;
}

double ownClosureNoiseScale(const std::vector<FactorPtr>& ownClosures,
                            const std::vector<FactorPtr>& odometry, const Values& poses) {
  FactorGraph graph;
  for (const FactorPtr& f : odometry) graph.add(f);
  for (const FactorPtr& f : ownClosures) graph.add(f);
  ConsistencyOptions options;
  options.odometryScale = 0.0;  // as the agreement test takes the maps
  options.calibrationOnly = true;
  return std::min(
      1.0, kFartherPairsMargin * pairwiseConsistentClosures(graph, poses, options).calibration);
}

}  // namespace loopd::server
