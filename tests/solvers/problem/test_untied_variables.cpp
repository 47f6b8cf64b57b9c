#include "solvers/problem/untied_variables.h"

#include <gtest/gtest.h>

#include <memory>

#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/landmark_factors.h"
#include "solvers/factors/prior_factors.h"

namespace loopd {
namespace {

FactorPtr between(int a, int b) {
  return std::make_shared<BetweenFactorSE2>(poseKey(a), poseKey(b), SE2(1, 0, 0),
                                            Eigen::Matrix3d::Identity(), FactorRole::Odometry);
}

Values posesUpTo(int n) {
  Values v;
  for (int i = 0; i < n; ++i) v.insert(poseKey(i), SE2(i, 0, 0));
  return v;
}

TEST(UntiedVariables, AConnectedGraphHasNone) {
  FactorGraph g;
  for (int i = 0; i + 1 < 4; ++i) g.add(between(i, i + 1));
  g.add(between(3, 0));
  EXPECT_TRUE(untiedVariables(g, posesUpTo(4), poseKey(0)).empty());
}

TEST(UntiedVariables, NamesThePartsTheGaugeDoesNotReach) {
  FactorGraph g;
  g.add(between(0, 1));
  g.add(between(2, 3));  // a second part
  // Pose 4: no factor at all.
  EXPECT_EQ(untiedVariables(g, posesUpTo(5), poseKey(0)),
            (std::vector<Key>{poseKey(2), poseKey(3), poseKey(4)}));
  // Seen from the other part, the first is the untied one.
  EXPECT_EQ(untiedVariables(g, posesUpTo(5), poseKey(2)),
            (std::vector<Key>{poseKey(0), poseKey(1), poseKey(4)}));
}

TEST(UntiedVariables, APriorTiesItsPart) {
  FactorGraph g;
  g.add(between(0, 1));
  g.add(between(2, 3));
  g.add(std::make_shared<PriorFactorSE2>(poseKey(3), SE2(3, 0, 0), Eigen::Matrix3d::Identity()));
  EXPECT_TRUE(untiedVariables(g, posesUpTo(4), poseKey(0)).empty());
}

TEST(UntiedVariables, ALandmarkSeenFromAnUntiedPartIsUntiedToo) {
  FactorGraph g;
  g.add(between(0, 1));
  Values v = posesUpTo(3);
  v.insertPoint2(landmarkKey(7), Eigen::Vector2d(1, 1));
  g.add(std::make_shared<PosePointFactor2>(poseKey(2), landmarkKey(7), Eigen::Vector2d(0, 1),
                                           Eigen::Matrix2d::Identity()));
  EXPECT_EQ(untiedVariables(g, v, poseKey(0)), (std::vector<Key>{poseKey(2), landmarkKey(7)}));
  g.add(std::make_shared<PosePointFactor2>(poseKey(1), landmarkKey(7), Eigen::Vector2d(0, 1),
                                           Eigen::Matrix2d::Identity()));
  EXPECT_TRUE(untiedVariables(g, v, poseKey(0)).empty());  // the landmark ties pose 2 in
}

}  // namespace
}  // namespace loopd
