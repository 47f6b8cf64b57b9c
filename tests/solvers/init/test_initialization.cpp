// initializeLinearFromLowestPose: the linear initialization anchored at the guess's lowest pose
// key, whatever order the guess holds its variables in; empty when there is nothing to anchor
// or nothing to use; with two robots, each robot's poses from the graph, joined or not.
#include <gtest/gtest.h>

#include "solvers/init/initialization.h"
#include "solvers/problem/pose_graph_problem.h"
#include "tests/robust/dataset_prefix.h"
#include "tests/solvers/init/two_robot_split.h"

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

// intel's first 200 poses as two robots joined through anchors (robot 1 from pose 100, its
// anchor put far off): in the common frame the start is the one-robot start. The anchored
// factors were left out before, and robot 1 stayed where the guess put it.
TEST(LinearInitialization, JoinsRobotsThroughTheirAnchors) {
  const PoseGraphProblem p = buildProblem(test::loadPrefix("intel.g2o:200"));
  const Values one = initializeLinearFromLowestPose(p.graph, p.initial);
  const test::TwoRobotSplit split =
      test::splitInTwo(p.graph, p.initial, 100, SE2(30.0, -20.0, 2.0));
  const Values own = initializeLinearFromLowestPose(split.graph, split.values);
  const Values two = inCommonFrame(own);
  ASSERT_EQ(two.size(), split.values.size());
  for (std::uint64_t i = 0; i < 200; ++i) {
    const SE2 a = one.se2(one.slot(poseKey(i)));
    const SE2 b = two.se2(two.slot(test::splitKey(poseKey(i), 100)));
    EXPECT_NEAR(a.between(b).vector().norm(), 0.0, 1e-6) << i;
  }
  // Robot 1's own frame stays pinned at its first pose; its anchor moved instead.
  EXPECT_NEAR(own.se2(own.slot(poseKey(0, 1))).vector().norm(), 0.0, 1e-12);
}

// Not joined (no anchors, nothing across): robot 1's poses come from its own odometry and
// closures, started at its first pose's guess, not left at a bent guess.
TEST(LinearInitialization, StartsEachUnjoinedRobotFromItsOwnFirstPose) {
  const PoseGraphProblem p = buildProblem(test::loadPrefix("intel.g2o:200"));
  test::TwoRobotSplit split = test::splitInTwo(p.graph, p.initial, 100, SE2(), false);
  Values bent = split.values;
  for (int s = 0; s < bent.size(); ++s)
    if (keyRobot(bent.key(s)) == 1 && keyIndex(bent.key(s)) > 0)
      bent.set(s, bent.se2(s) * SE2(0.5, -0.3, 0.2));
  const Values start = initializeLinearFromLowestPose(split.graph, bent);
  FactorGraph robotOne;
  Values robotOneGuess;
  for (const FactorPtr& f : split.graph.factors())
    if (keyRobot(f->key(0)) == 1) robotOne.add(f);
  for (int s = 0; s < bent.size(); ++s)
    if (keyRobot(bent.key(s)) == 1) robotOneGuess.insertFrom(bent, s);
  const Values alone = initializeLinear(robotOne, robotOneGuess, poseKey(0, 1));
  for (int s = 0; s < alone.size(); ++s)
    EXPECT_NEAR(alone.se2(s).between(start.se2(start.slot(alone.key(s)))).vector().norm(), 0.0,
                1e-9)
        << s;
  EXPECT_GT(alone.se2(alone.slot(poseKey(50, 1)))
                .between(bent.se2(bent.slot(poseKey(50, 1))))
                .vector()
                .norm(),
            0.1);
}

}  // namespace
}  // namespace loopd
