// Each robot's map relaxed on its own factors alone (server/own_map_relaxation.h): two robots walk
// two laps of the square each, in their own frames, with exact odometry and a loop closure per
// lap; their maps are bent as a wrong join's pull would bend them, and the relaxation takes the
// bend out while each robot's first pose stays where it was.
#include <gtest/gtest.h>

#include <cmath>

#include "server/own_map_relaxation.h"
#include "solvers/factors/between_factor_se2.h"
#include "tests/robust/square_walk.h"

namespace loopd::server {
namespace {

using square::kLap;
using square::walk;

const Eigen::Matrix3d kInfo = Eigen::Vector3d(100, 100, 10000).asDiagonal();
constexpr int kPoses = 2 * kLap;

struct TwoRobots {
  std::vector<FactorPtr> factors;
  Values truth;  // each robot's map in its own frame, its first pose at `origin(r)`
  static SE2 origin(std::uint32_t r) { return r == 0 ? SE2() : SE2(3, 4, 0.7); }
  TwoRobots() {
    for (std::uint32_t r = 0; r < 2; ++r) {
      for (int i = 0; i < kPoses; ++i) {
        truth.insert(poseKey(static_cast<std::uint64_t>(i), r), origin(r) * walk(i));
        if (i + 1 < kPoses)
          factors.push_back(std::make_shared<BetweenFactorSE2>(
              poseKey(static_cast<std::uint64_t>(i), r),
              poseKey(static_cast<std::uint64_t>(i + 1), r), walk(i).between(walk(i + 1)), kInfo,
              FactorRole::Odometry));
        if (i >= kLap)  // the second lap revisits the first
          factors.push_back(std::make_shared<BetweenFactorSE2>(
              poseKey(static_cast<std::uint64_t>(i - kLap), r),
              poseKey(static_cast<std::uint64_t>(i), r), walk(i - kLap).between(walk(i)), kInfo,
              FactorRole::LoopClosure));
      }
    }
  }
  // Each map turned more and more along its chain about its first pose, as a pull on its tail
  // would leave it: 0.02 rad a pose, 1.6 rad at the end.
  Values bent() const {
    Values v = truth;
    for (int s = 0; s < v.size(); ++s) {
      const double index = static_cast<double>(keyIndex(v.key(s)));
      const SE2 o = origin(keyRobot(v.key(s)));
      v.set(s, o * SE2(0, 0, 0.02 * index) * o.inverse() * v.se2(s));
    }
    return v;
  }
};

double largestError(const Values& a, const Values& b) {
  double worst = 0.0;
  for (int s = 0; s < a.size(); ++s) {
    const SE2 d = a.se2(s).between(b.se2(b.slot(a.key(s))));
    worst = std::max({worst, std::hypot(d.x, d.y), std::abs(d.theta)});
  }
  return worst;
}

void expectSamePose(const Values& a, const Values& b, Key k) {
  const SE2 x = a.se2(a.slot(k)), y = b.se2(b.slot(k));
  EXPECT_EQ(x.x, y.x);
  EXPECT_EQ(x.y, y.y);
  EXPECT_EQ(x.theta, y.theta);
}

TEST(OwnMapRelaxation, TakesOutABendEachRobotsOwnFactorsContradict) {
  const TwoRobots robots;
  Values poses = robots.bent();
  ASSERT_GT(largestError(poses, robots.truth), 1.0);
  relaxOwnMaps(robots.factors, poses, kRelaxIterations);
  EXPECT_LT(largestError(poses, robots.truth), 1e-6);
}

TEST(OwnMapRelaxation, HoldsTheLowestPoseOfEachConnectedPart) {
  TwoRobots robots;
  // Robot 1's odometry broken between poses 9 and 10, its closures gone: two parts.
  std::vector<FactorPtr> broken;
  for (const FactorPtr& f : robots.factors)
    if (keyRobot(f->key(0)) == 0 || (f->role() == FactorRole::Odometry && keyIndex(f->key(0)) != 9))
      broken.push_back(f);
  Values poses = robots.bent();
  const Values before = poses;
  relaxOwnMaps(broken, poses, kRelaxIterations);
  for (const Key k : {poseKey(0, 0), poseKey(0, 1), poseKey(10, 1)})
    expectSamePose(poses, before, k);
  // Robot 1's second part keeps its bent start, so its shape, not its place, is mended.
  const SE2 start = poses.se2(poses.slot(poseKey(10, 1)));
  const SE2 truthStart = robots.truth.se2(robots.truth.slot(poseKey(10, 1)));
  for (int i = 10; i < kPoses; ++i) {
    const Key k = poseKey(static_cast<std::uint64_t>(i), 1);
    const SE2 d = start.between(poses.se2(poses.slot(k)))
                      .between(truthStart.between(robots.truth.se2(robots.truth.slot(k))));
    EXPECT_LT(std::hypot(d.x, d.y) + std::abs(d.theta), 1e-6) << "pose " << i;
  }
}

TEST(OwnMapRelaxation, LeavesOutFactorsOnPosesItWasNotGiven) {
  const TwoRobots robots;
  const Values bent = robots.bent();
  Values poses;  // robot 0 only: robot 1's factors have no poses here
  for (int s = 0; s < bent.size(); ++s)
    if (keyRobot(bent.key(s)) == 0) poses.insertFrom(bent, s);
  relaxOwnMaps(robots.factors, poses, kRelaxIterations);
  EXPECT_EQ(poses.size(), kPoses);
  EXPECT_LT(largestError(poses, robots.truth), 1e-6);
}

TEST(OwnMapRelaxation, LeavesThePosesAsTheyWereWithoutFactors) {
  const TwoRobots robots;
  Values poses = robots.bent();
  const Values before = poses;
  relaxOwnMaps({}, poses, kRelaxIterations);
  for (const Key k : before.keys()) expectSamePose(poses, before, k);
}

TEST(OwnMapRelaxation, TakesBackTheClosuresThatFitAndNoOthers) {
  const TwoRobots robots;
  const Key a = poseKey(3, 0), b = poseKey(3 + kLap, 0);
  const SE2 z = walk(3).between(walk(3 + kLap));
  const auto fits = std::make_shared<BetweenFactorSE2>(a, b, z, kInfo, FactorRole::LoopClosure);
  // 1 m off at σ 0.1 m: χ² 100, above χ²₃(0.999) = 16.3.
  const auto wrong = std::make_shared<BetweenFactorSE2>(a, b, z * SE2(1.0, 0.0, 0.0), kInfo,
                                                        FactorRole::LoopClosure);
  const auto unknown =
      std::make_shared<BetweenFactorSE2>(a, poseKey(500, 0), z, kInfo, FactorRole::LoopClosure);
  const std::vector<FactorPtr> back = closuresThatFit({fits, wrong, unknown}, robots.truth);
  ASSERT_EQ(back.size(), 1u);
  EXPECT_EQ(back.front(), fits);
}

}  // namespace
}  // namespace loopd::server
