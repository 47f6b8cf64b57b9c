// The pairwise-consistency (PCM) selection: on a trajectory that circles a square three
// times, the true revisits form one mutually consistent set and wrong closures do not join
// it; closures it cannot judge are left out; 2D and 3D alike.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <random>

#include "robust/pairwise_consistency.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/geometry/so3.h"

namespace loopd {
namespace {

constexpr int kLap = 40;  // poses per lap of the square (10 a side)

// Pose i of the square walk: 1 m steps, a quarter turn at each corner.
SE2 walk(int i) {
  SE2 x;
  for (int k = 0; k < i; ++k) x = x * SE2(1.0, 0.0, (k + 1) % 10 == 0 ? M_PI / 2 : 0.0);
  return x;
}

SE3 lift(const SE2& x) { return SE3(expSO3(Vec3(0, 0, x.theta)), Vec3(x.x, x.y, 0.0)); }

struct Scenario {
  FactorGraph graph;
  Values odometry;
  std::vector<int> trueClosures, wrongClosures;
};

// Three laps with exact odometry (σ 0.1 m, 0.01 rad a step); closures (σ 0.1 m, 0.01 rad)
// from lap 3 back to laps 1 and 2 (true: the same spot, measured exactly) and `wrong` random
// pairs measured 2–4 m and 0.5–1 rad off their true relative pose.
Scenario square(bool in3d, int wrong, unsigned seed) {
  Scenario s;
  const int n = 3 * kLap;
  auto between = [&](int i, int j, const SE2& z, FactorRole role) {
    const double rotationInformation = 1e4;
    if (in3d) {
      Mat6 information = Mat6::Identity() * 100.0;
      information.bottomRightCorner<3, 3>() *= rotationInformation / 100.0;
      s.graph.add(
          std::make_shared<BetweenFactorSE3>(poseKey(i), poseKey(j), lift(z), information, role));
    } else {
      const Eigen::Matrix3d information =
          Eigen::Vector3d(100.0, 100.0, rotationInformation).asDiagonal();
      s.graph.add(std::make_shared<BetweenFactorSE2>(poseKey(i), poseKey(j), z, information, role));
    }
  };
  for (int i = 0; i < n; ++i) {
    if (in3d)
      s.odometry.insert(poseKey(i), lift(walk(i)));
    else
      s.odometry.insert(poseKey(i), walk(i));
    if (i > 0) between(i - 1, i, walk(i - 1).between(walk(i)), FactorRole::Odometry);
  }
  for (int i = 2 * kLap; i < n; i += 3) {
    s.trueClosures.push_back(s.graph.size());
    between(i - kLap, i, SE2(), FactorRole::LoopClosure);
    s.trueClosures.push_back(s.graph.size());
    between(i - 2 * kLap, i, SE2(), FactorRole::LoopClosure);
  }
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> pose(0, n - 1);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  auto sign = [&] { return u(rng) < 0.5 ? -1.0 : 1.0; };
  for (int k = 0; k < wrong; ++k) {
    int a = pose(rng), b = pose(rng);
    if (std::abs(a - b) < 2) b = (a + 5) % n;
    const double heading = 2.0 * M_PI * u(rng), off = 2.0 + 2.0 * u(rng);
    const SE2 error(off * std::cos(heading), off * std::sin(heading),
                    sign() * (0.5 + 0.5 * u(rng)));
    s.wrongClosures.push_back(s.graph.size());
    between(a, b, walk(a).between(walk(b)) * error, FactorRole::LoopClosure);
  }
  return s;
}

void expectTrueSetFound(bool in3d) {
  const Scenario s = square(in3d, 30, 7);
  const ConsistentSet set = pairwiseConsistentClosures(s.graph, s.odometry);
  EXPECT_EQ(set.judged, static_cast<int>(s.trueClosures.size() + s.wrongClosures.size()));
  for (int i : s.trueClosures) EXPECT_TRUE(set.member[i]) << "true closure " << i;
  int wrongIn = 0;
  for (int i : s.wrongClosures) wrongIn += set.member[i];
  EXPECT_EQ(wrongIn, 0);
  EXPECT_EQ(set.size, static_cast<int>(s.trueClosures.size()) + wrongIn);
  for (int i = 0; i < s.graph.size(); ++i)
    if (s.graph[i]->role() == FactorRole::Odometry) EXPECT_FALSE(set.member[i]);
}

TEST(PairwiseConsistency, KeepsTheTrueRevisitsAndNoWrongClosure2D) { expectTrueSetFound(false); }

TEST(PairwiseConsistency, KeepsTheTrueRevisitsAndNoWrongClosure3D) { expectTrueSetFound(true); }

// The stated uncertainty decides: a closure 1.5 m off is inconsistent with the exact revisits
// near it under the stated information, and joins them once odometry and closures are
// declared 100× noisier (the scales the solver passes when the information is miscalibrated).
TEST(PairwiseConsistency, OdometryScaleWidensTheTest) {
  Scenario s = square(false, 0, 1);
  const int offset = s.graph.size();
  s.graph.add(std::make_shared<BetweenFactorSE2>(
      poseKey(kLap + 5), poseKey(2 * kLap + 5), SE2(1.5, 0.0, 0.0),
      Eigen::Matrix3d::Identity() * 100.0, FactorRole::LoopClosure));
  EXPECT_FALSE(pairwiseConsistentClosures(s.graph, s.odometry).member[offset]);
  ConsistencyOptions loose;
  loose.odometryScale = 100.0;
  loose.closureScale = 100.0;
  EXPECT_TRUE(pairwiseConsistentClosures(s.graph, s.odometry, loose).member[offset]);
}

// A closure to a pose off the chain (a second robot's, without odometry) has no partner to
// agree with: judged, but not in the set.
TEST(PairwiseConsistency, LeavesOutAClosureNothingAgreesWith) {
  Scenario s = square(false, 0, 1);
  s.odometry.insert(poseKey(0, 1), SE2());
  const int other = s.graph.size();
  s.graph.add(std::make_shared<BetweenFactorSE2>(
      poseKey(3), poseKey(0, 1), SE2(), Eigen::Matrix3d::Identity(), FactorRole::LoopClosure));
  const ConsistentSet set = pairwiseConsistentClosures(s.graph, s.odometry);
  EXPECT_EQ(set.judged, static_cast<int>(s.trueClosures.size()) + 1);
  EXPECT_FALSE(set.member[other]);
  EXPECT_EQ(set.size, static_cast<int>(s.trueClosures.size()));
}

}  // namespace
}  // namespace loopd
