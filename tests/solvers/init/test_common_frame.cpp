// Several robots' values in the common frame and back, and inter-robot closures through anchors
// as plain between factors of common-frame poses.
#include "solvers/init/common_frame.h"

#include <gtest/gtest.h>

#include "solvers/problem/pose_graph_problem.h"
#include "tests/robust/dataset_prefix.h"
#include "tests/solvers/init/two_robot_split.h"

namespace loopd {
namespace {

TEST(CommonFrame, SeveralFramesMeansAnAnchorOrASecondRobot) {
  Values one;
  one.insert(poseKey(0), SE2());
  one.insert(poseKey(1), SE2(1, 0, 0));
  EXPECT_FALSE(holdsSeveralFrames(one));
  Values two = one;
  two.insert(poseKey(0, 1), SE2());
  EXPECT_TRUE(holdsSeveralFrames(two));
  one.insert(anchorKey(0), SE2());
  EXPECT_TRUE(holdsSeveralFrames(one));
}

// Common-frame values are A_r·x; back in own frames, each robot's lowest pose stays where it
// was and the anchor takes the rest: a round trip changes nothing, and a common-frame move of
// robot 1 as a whole lands in its anchor alone.
TEST(CommonFrame, RoundTripsAndMovesFramesThroughTheirAnchors) {
  const PoseGraphProblem p = buildProblem(test::loadPrefix("intel.g2o:60"));
  const SE2 anchor(4.0, -2.0, 0.7);
  const test::TwoRobotSplit split = test::splitInTwo(p.graph, p.initial, 30, anchor);
  const Values common = inCommonFrame(split.values);
  const SE2 x = split.values.se2(split.values.slot(poseKey(7, 1)));
  const SE2 X = common.se2(common.slot(poseKey(7, 1)));
  EXPECT_NEAR((anchor * x).between(X).vector().norm(), 0.0, 1e-12);
  const Values back = inOwnFrames(common, split.values);
  for (int s = 0; s < back.size(); ++s)
    EXPECT_NEAR(back.se2(s).between(split.values.se2(s)).vector().norm(), 0.0, 1e-9) << s;

  Values moved = common;
  const SE2 shift(1.0, 2.0, -0.3);
  for (int s = 0; s < moved.size(); ++s)
    if (keyRobot(moved.key(s)) == 1 && keyKind(moved.key(s)) == KeyKind::Pose)
      moved.set(s, shift * moved.se2(s));
  const Values own = inOwnFrames(moved, split.values);
  EXPECT_NEAR(own.se2(own.slot(anchorKey(1))).between(shift * anchor).vector().norm(), 0.0, 1e-9);
  EXPECT_NEAR(own.se2(own.slot(poseKey(7, 1))).between(x).vector().norm(), 0.0, 1e-9);
}

TEST(CommonFrame, AnchoredBetweensBecomePlainOnes) {
  const PoseGraphProblem p = buildProblem(test::loadPrefix("intel.g2o:60"));
  const test::TwoRobotSplit split = test::splitInTwo(p.graph, p.initial, 30, SE2(4, -2, 0.7));
  const FactorGraph plain = withAnchoredBetweensPlain(split.graph);
  ASSERT_EQ(plain.size(), split.graph.size());
  const Values common = inCommonFrame(split.values);
  int anchored = 0;
  for (int i = 0; i < plain.size(); ++i) {
    EXPECT_EQ(plain[i]->id(), split.graph[i]->id());
    EXPECT_EQ(plain[i]->role(), split.graph[i]->role());
    EXPECT_EQ(plain[i]->size(), 2);
    if (split.graph[i]->size() == 4) ++anchored;
    EXPECT_NEAR(plain[i]->chi2(common), split.graph[i]->chi2(split.values), 1e-9) << i;
  }
  EXPECT_GT(anchored, 0);  // the split's odometry step at least
}

// A robot with an anchor but no pose (a landmark namespace) keeps its anchor, and its
// landmarks come back to where they were.
TEST(CommonFrame, ARobotWithoutPosesKeepsItsAnchor) {
  Values v;
  v.insert(poseKey(0), SE2(1, 2, 0.3));
  v.insert(anchorKey(0), SE2());
  v.insert(anchorKey(5), SE2(3.0, -1.0, 0.4));
  v.insertPoint2(landmarkKey(7, 5), Vec2(2.0, 1.0));
  const Values back = inOwnFrames(inCommonFrame(v), v);
  EXPECT_NEAR((back.point2(back.slot(landmarkKey(7, 5))) - Vec2(2.0, 1.0)).norm(), 0.0, 1e-12);
  EXPECT_NEAR(back.se2(back.slot(anchorKey(5))).between(SE2(3.0, -1.0, 0.4)).vector().norm(), 0.0,
              1e-12);
}

}  // namespace
}  // namespace loopd
