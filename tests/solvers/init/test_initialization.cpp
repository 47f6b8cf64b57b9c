// initializeLinearFromLowestPose: the linear initialization anchored at the guess's lowest pose
// key, whatever order the guess holds its variables in; empty when there is nothing to anchor
// or nothing to use.
#include <gtest/gtest.h>

#include "solvers/init/initialization.h"
#include "solvers/problem/pose_graph_problem.h"
#include "tests/robust/dataset_prefix.h"

namespace loopd {
namespace {

TEST(LinearInitialization, AnchorsAtTheLowestPoseKey) {
  const PoseGraphProblem p = buildProblem(test::loadPrefix("intel.g2o:200"));
  // The guess with its variables in reverse order: the lowest key is its last slot.
  Values reversed;
  for (int s = p.initial.size() - 1; s >= 0; --s) reversed.insertFrom(p.initial, s);
  const Values byLowest = initializeLinearFromLowestPose(p.graph, reversed);
  const Values byAnchor = initializeLinear(p.graph, reversed, poseKey(0));
  ASSERT_EQ(byLowest.size(), reversed.size());
  for (int s = 0; s < byLowest.size(); ++s) {
    const int t = byAnchor.slot(byLowest.key(s));
    ASSERT_GE(t, 0);
    for (int k = 0; k < 3; ++k) EXPECT_EQ(byLowest.data(s)[k], byAnchor.data(t)[k]);
  }
  // The anchor keeps its guessed value.
  const int anchor = byLowest.slot(poseKey(0));
  for (int k = 0; k < 3; ++k)
    EXPECT_EQ(byLowest.data(anchor)[k], p.initial.data(p.initial.slot(poseKey(0)))[k]);
}

TEST(LinearInitialization, EmptyWithoutAPoseOrAFactor) {
  const PoseGraphProblem p = buildProblem(test::loadPrefix("intel.g2o:20"));
  EXPECT_EQ(initializeLinearFromLowestPose(p.graph, Values()).size(), 0);
  EXPECT_EQ(initializeLinearFromLowestPose(FactorGraph(), p.initial).size(), 0);
}

}  // namespace
}  // namespace loopd
