// What adding or removing closures would do, predicted from the joint marginal without a
// re-solve, against actually re-solving (a two-lap square walk, a cluster of three closures
// measured off by 0.3 m); and the clustering of closures by their ends, between robots too.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>

#include "robust/closure_leverage.h"
#include "solvers/batch/batch_backend.h"
#include "solvers/factors/anchored_between_factor.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/prior_factors.h"
#include "tests/robust/square_walk.h"

namespace loopd {
namespace {

using square::kLap;
using square::walk;

FactorPtr between(int i, int j, const SE2& z, FactorRole role, FactorId id) {
  auto f = std::make_shared<BetweenFactorSE2>(
      poseKey(i), poseKey(j), z, Eigen::Vector3d(100.0, 100.0, 1e4).asDiagonal(), role);
  f->setId(id);
  return f;
}

// Two laps, noisy odometry, true revisits every 4th pose of lap 2; the group: three
// neighbouring revisits measured 0.3 m off (biased, so adding or removing them moves the map).
struct Walk {
  FactorGraph all;  // every factor, group included
  BackendUpdate withoutGroup;
  std::vector<int> group;  // indices into all
};

Walk twoLaps() {
  Walk w;
  std::mt19937 rng(3);
  std::normal_distribution<double> gauss(0.0, 1.0);
  auto noisy = [&](const SE2& z) {
    return z * SE2(0.1 * gauss(rng), 0.1 * gauss(rng), 0.01 * gauss(rng));
  };
  FactorId id = 0;
  auto add = [&](const FactorPtr& f, bool inGroup) {
    if (inGroup)
      w.group.push_back(w.all.size());
    else
      w.withoutGroup.factors.push_back(f);
    w.all.add(f);
  };
  SE2 composed;
  for (int i = 0; i < 2 * kLap; ++i) {
    if (i > 0) {
      const SE2 z = noisy(walk(i - 1).between(walk(i)));
      add(between(i - 1, i, z, FactorRole::Odometry, id++), false);
      composed = composed * z;
    }
    w.withoutGroup.initial.insert(poseKey(i), composed);
  }
  for (int i = kLap + 2; i < 2 * kLap; i += 4) {
    const bool inGroup = i >= kLap + 14 && i <= kLap + 22;
    const SE2 z = inGroup ? SE2(0.3, 0.0, 0.0) : noisy(SE2());
    add(between(i - kLap, i, z, FactorRole::LoopClosure, id++), inGroup);
  }
  return w;
}

double totalChi2(const Backend& b) {
  double c = 0.0;
  for (int i = 0; i < b.graph().size(); ++i) c += b.graph()[i]->chi2(b.estimate());
  return c;
}

JointMarginalsFn marginalsOf(BatchBackend& b) {
  return [&b](const std::vector<std::vector<Key>>& sets) { return b.jointMarginals(sets); };
}

TEST(ClosureLeverage, PredictsAddingAndRemovingAGroup) {
  Walk w = twoLaps();
  ASSERT_EQ(w.group.size(), 3u);
  BatchBackend backend{BackendOptions{}};
  backend.update(w.withoutGroup);
  backend.optimize();
  const double without = totalChi2(backend);

  const std::vector<double> add = predictedCostChange(w.all, backend.estimate(), {w.group},
                                                      GroupChange::Add, marginalsOf(backend));
  BackendUpdate group;
  for (int i : w.group) group.factors.push_back(w.all[i]);
  backend.update(group);
  backend.optimize();
  const double with = totalChi2(backend);
  ASSERT_GT(with - without, 10.0);  // the group does bend the map
  EXPECT_NEAR(add[0], with - without, 0.03 * (with - without));

  // Removing it again, predicted at the solution that holds it.
  const std::vector<double> remove = predictedCostChange(w.all, backend.estimate(), {w.group},
                                                         GroupChange::Remove, marginalsOf(backend));
  EXPECT_NEAR(remove[0], with - without, 0.03 * (with - without));

  // Alone, each closure is held back by the others: the group's removal gains more than its
  // members' removals one by one.
  const std::vector<double> single =
      predictedCostChange(w.all, backend.estimate(), {{w.group[0]}, {w.group[1]}, {w.group[2]}},
                          GroupChange::Remove, marginalsOf(backend));
  EXPECT_GT(remove[0], single[0] + single[1] + single[2]);
}

TEST(ClosureLeverage, UnknownVariableIsNaN) {
  Walk w = twoLaps();
  BatchBackend backend{BackendOptions{}};
  backend.update(w.withoutGroup);
  backend.optimize();
  FactorGraph graph = w.all;
  graph.add(between(3, 999, SE2(), FactorRole::LoopClosure, 1000));
  const std::vector<double> change =
      predictedCostChange(graph, backend.estimate(), {{graph.size() - 1}, {w.group[0]}},
                          GroupChange::Add, marginalsOf(backend));
  EXPECT_TRUE(std::isnan(change[0]));
  EXPECT_TRUE(std::isfinite(change[1]));
}

TEST(ClosureLeverage, ClustersJoinClosuresWithNearbyEnds) {
  FactorGraph graph;
  Values values;
  for (int i = 0; i < 400; ++i) values.insert(poseKey(i), SE2());
  graph.add(between(10, 50, SE2(), FactorRole::LoopClosure, 0));
  graph.add(between(52, 12, SE2(), FactorRole::LoopClosure, 1));  // ends either way round
  graph.add(between(16, 56, SE2(), FactorRole::LoopClosure, 2));  // chained through 1
  graph.add(between(30, 80, SE2(), FactorRole::LoopClosure, 3));
  graph.add(between(11, 300, SE2(), FactorRole::LoopClosure, 4));  // one end near, one far
  graph.add(std::make_shared<PriorFactorSE2>(poseKey(10), SE2(), Eigen::Matrix3d::Identity()));
  auto clusters = closureClusters(graph, values, {0, 1, 2, 3, 4, 5}, 5);
  for (auto& c : clusters) std::sort(c.begin(), c.end());
  std::sort(clusters.begin(), clusters.end());
  const std::vector<std::vector<int>> expected = {{0, 1, 2}, {3}, {4}, {5}};
  EXPECT_EQ(clusters, expected);
}

// Closures between two robots, through their anchors (A_r, x_r, A_s, y_s), cluster by their
// poses like any other (they were clusters of their own, so a group of wrong ones between the
// robots was never dropped together).
TEST(ClosureLeverage, ClustersClosuresBetweenRobotsByTheirPoses) {
  FactorGraph graph;
  Values values;
  for (std::uint32_t robot = 0; robot < 2; ++robot)
    for (int i = 0; i < 200; ++i) values.insert(poseKey(i, robot), SE2());
  const Key a0 = anchorKey(0), a1 = anchorKey(1);
  values.insert(a0, SE2());
  values.insert(a1, SE2());
  auto across = [&](Key ar, Key x, Key as, Key y) {
    graph.add(std::make_shared<AnchoredBetweenFactorSE2>(
        ar, x, as, y, SE2(), Eigen::Matrix3d::Identity(), FactorRole::LoopClosure));
  };
  across(a0, poseKey(10, 0), a1, poseKey(50, 1));
  across(a1, poseKey(52, 1), a0, poseKey(12, 0));  // sent from the other robot
  across(a0, poseKey(100, 0), a1, poseKey(50, 1));
  auto clusters = closureClusters(graph, values, {0, 1, 2}, 5);
  for (auto& c : clusters) std::sort(c.begin(), c.end());
  std::sort(clusters.begin(), clusters.end());
  const std::vector<std::vector<int>> expected = {{0, 1}, {2}};
  EXPECT_EQ(clusters, expected);
}

}  // namespace
}  // namespace loopd
