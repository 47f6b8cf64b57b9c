#include "server/closure_agreement.h"

#include "robust/pairwise_consistency.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/graph/factor_graph.h"

namespace loopd::server {

namespace {

// The closure from the lower robot to the higher, as a loop closure (the role PCM judges,
// whatever the sender gave): PCM pairs closures whose first ends lie on one chain and second
// ends on another, and keys sort robot by robot.
FactorPtr fromLowerRobot(const FactorPtr& f) {
  const bool flip = keyRobot(f->key(0)) > keyRobot(f->key(1));
  const Key a = flip ? f->key(1) : f->key(0), b = flip ? f->key(0) : f->key(1);
  if (const auto* z = dynamic_cast<const BetweenFactorSE2*>(f.get()))
    return std::make_shared<BetweenFactorSE2>(a, b, flip ? z->measured().inverse() : z->measured(),
                                              z->information(), FactorRole::LoopClosure);
  const auto& z3 = static_cast<const BetweenFactorSE3&>(*f);
  return std::make_shared<BetweenFactorSE3>(a, b, flip ? z3.measured().inverse() : z3.measured(),
                                            z3.information(), FactorRole::LoopClosure);
}

}  // namespace

std::vector<size_t> agreeingClosures(const std::vector<FactorPtr>& closures,
                                     const std::vector<FactorPtr>& odometry, const Values& poses,
                                     double probability) {
  FactorGraph graph;
  for (const FactorPtr& f : odometry) graph.add(f);
  const int first = graph.size();
  for (const FactorPtr& f : closures) graph.add(fromLowerRobot(f));
  ConsistencyOptions options;
  options.probability = probability;
  // Each robot's map is taken as exact between the closures' ends: two closures agree when
  // they place the frames within their own noise. The odometry's drift, added, made the test
  // so wide over long chains that two random wrong closures agreed (intel: σ_θ 0.067 rad per
  // step stated); true closures of one revisit still agree without it. The short-cycle
  // calibration only ever narrows the test, and it has too few pairs here to act.
  options.odometryScale = 0.0;
  options.calibrationWindow = 0;
  const ConsistentSet set = pairwiseConsistentClosures(graph, poses, options);
  std::vector<size_t> out;
  for (size_t i = 0; i < closures.size(); ++i)
    if (set.member[static_cast<size_t>(first) + i]) out.push_back(i);
  return out;
}

}  // namespace loopd::server
