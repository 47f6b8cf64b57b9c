// Which of a robot pair's inter-robot loop closures agree on the transform between the robots'
// frames (server/closure_agreement.h): two robots walk the same square, each in its own frame;
// the closures between them at the same spots agree, in either direction, and wrong ones do not.
#include <gtest/gtest.h>

#include <random>

#include "server/closure_agreement.h"
#include "solvers/factors/between_factor_se2.h"
#include "tests/robust/square_walk.h"

namespace loopd::server {
namespace {

using square::kLap;
using square::walk;

const Eigen::Matrix3d kInfo = Eigen::Vector3d(100, 100, 10000).asDiagonal();  // σ 0.1 m, 0.01 rad

struct TwoRobots {
  Eigen::Matrix3d info = kInfo;  // the closures' stated information
  std::vector<FactorPtr> odometry;
  Values poses;  // the odometry composed, each robot in its own frame
  std::mt19937 rng{3};
  std::normal_distribution<double> gauss{0.0, 1.0};
  SE2 noisy(const SE2& z) {
    return z * SE2(0.02 * gauss(rng), 0.02 * gauss(rng), 0.002 * gauss(rng));
  }
  // Robot 1 walks the square's second lap, from its own origin (the world's T1 = its start).
  TwoRobots() {
    for (std::uint32_t r = 0; r < 2; ++r) {
      SE2 x = r == 0 ? SE2() : SE2(3, 4, 0.7);  // either frame will do: only cycles matter
      for (int i = 0; i < kLap; ++i) {
        poses.insert(poseKey(static_cast<std::uint64_t>(i), r), x);
        if (i + 1 == kLap) break;
        const SE2 z = noisy(walk(i).between(walk(i + 1)));
        odometry.push_back(std::make_shared<BetweenFactorSE2>(
            poseKey(static_cast<std::uint64_t>(i), r),
            poseKey(static_cast<std::uint64_t>(i + 1), r), z, kInfo, FactorRole::Odometry));
        x = x * z;
      }
    }
  }
  // Robot 0's pose i to robot 1's pose j, measured as the truth is (or `off` it).
  FactorPtr closure(int i, int j, const SE2& off = SE2()) {
    return std::make_shared<BetweenFactorSE2>(
        poseKey(static_cast<std::uint64_t>(i), 0), poseKey(static_cast<std::uint64_t>(j), 1),
        noisy(walk(i).between(walk(j))) * off, info, FactorRole::LoopClosure);
  }
  // `n` closures of each robot's own, from its pose i to its pose i + 10 for i < n, measured
  // as the truth is: neighbours pair up as closures of one revisit do.
  std::vector<FactorPtr> ownRevisits(int n) {
    std::vector<FactorPtr> out;
    for (std::uint32_t r = 0; r < 2; ++r)
      for (int i = 0; i < n; ++i)
        out.push_back(std::make_shared<BetweenFactorSE2>(
            poseKey(static_cast<std::uint64_t>(i), r),
            poseKey(static_cast<std::uint64_t>(i + 10), r), noisy(walk(i).between(walk(i + 10))),
            info, FactorRole::LoopClosure));
    return out;
  }
  FactorPtr reversed(int i, int j) {  // sent by robot 1: its pose j to robot 0's pose i
    return std::make_shared<BetweenFactorSE2>(
        poseKey(static_cast<std::uint64_t>(j), 1), poseKey(static_cast<std::uint64_t>(i), 0),
        noisy(walk(j).between(walk(i))), info, FactorRole::LoopClosure);
  }
};

TEST(ClosureAgreement, TheTrueClosuresAgreeInEitherDirectionAndWrongOnesDoNot) {
  TwoRobots t;
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<FactorPtr> closures;
  std::vector<size_t> expected;
  for (int i = 0; i < 12; ++i) {
    if (i % 3 == 0) {  // true: the same spot of the square, one of them sent the other way
      expected.push_back(closures.size());
      closures.push_back(i == 6 ? t.reversed(5 + i, 5 + i) : t.closure(5 + i, 5 + i));
    } else {  // wrong: 2–4 m and 0.5–1 rad off the truth
      const double a = 2 * M_PI * u(t.rng), d = 2 + 2 * u(t.rng);
      closures.push_back(t.closure(static_cast<int>(u(t.rng) * kLap),
                                   static_cast<int>(u(t.rng) * kLap),
                                   SE2(d * std::cos(a), d * std::sin(a),
                                       (u(t.rng) < 0.5 ? -1 : 1) * (0.5 + 0.5 * u(t.rng)))));
    }
  }
  EXPECT_EQ(agreeingClosures(closures, t.odometry, t.poses, 0.999), expected);
}

TEST(ClosureAgreement, OneClosureOrOnlyWrongOnesAgreeOnNothing) {
  TwoRobots t;
  EXPECT_LE(agreeingClosures({t.closure(3, 3)}, t.odometry, t.poses, 0.999).size(), 1u);
  const std::vector<FactorPtr> wrong = {t.closure(3, 20, SE2(3, 0, 0.6)),
                                        t.closure(12, 7, SE2(-2, 2, -0.8)),
                                        t.closure(30, 31, SE2(0, -3, 1.0))};
  EXPECT_LE(agreeingClosures(wrong, t.odometry, t.poses, 0.999).size(), 1u);
}

TEST(ClosureAgreement, ClosuresAcrossAGapInARobotsOdometryAreNotJudged) {
  TwoRobots t;
  // Robot 1's odometry from pose 10 to 11 missing: its poses 5 and 15 are on different chains.
  std::vector<FactorPtr> odometry;
  for (const FactorPtr& f : t.odometry)
    if (!(keyRobot(f->key(0)) == 1 && keyIndex(f->key(0)) == 10)) odometry.push_back(f);
  EXPECT_LE(agreeingClosures({t.closure(5, 5), t.closure(15, 15)}, odometry, t.poses, 0.999).size(),
            1u);
  EXPECT_EQ(
      agreeingClosures({t.closure(5, 5), t.closure(15, 15)}, t.odometry, t.poses, 0.999).size(),
      2u);
}

// parking-garage states its closures' noise as σ 1 m and 0.5–1 rad; its optimum leaves them
// millimetres off. Judged at such a stated noise, two wrong closures agree over the lever arm
// of a robot's map (they joined two of its robots, and mm then rejected thousands of true
// closures); judged at the noise the robots' own closures show, only the true ones agree.
TEST(ClosureAgreement, TheRobotsOwnClosuresNarrowATestTheirStatedNoiseLeavesWide) {
  TwoRobots t;
  t.info = kInfo / 1e4;  // stated σ 10 m, 1 rad; the real noise is σ 2 cm, 0.002 rad a step
  const std::vector<FactorPtr> wrong = {t.closure(3, 20, SE2(3, 0, 0.6)),
                                        t.closure(12, 7, SE2(-2, 2, -0.8))};
  const std::vector<FactorPtr> right = {t.closure(5, 5), t.closure(8, 8)};
  ASSERT_EQ(agreeingClosures(wrong, t.odometry, t.poses, 0.999).size(), 2u);

  const double scale = ownClosureNoiseScale(t.ownRevisits(30), t.odometry, t.poses);
  EXPECT_LT(scale, 1e-2);
  EXPECT_LE(agreeingClosures(wrong, t.odometry, t.poses, 0.999, scale).size(), 1u);
  EXPECT_EQ(agreeingClosures(right, t.odometry, t.poses, 0.999, scale).size(), 2u);
}

TEST(ClosureAgreement, TooFewOwnRevisitsOrOnesThatFitWorseThanStatedLeaveTheTestAsStated) {
  TwoRobots t;
  t.info = kInfo / 100;  // stated σ 1 m, 0.1 rad
  EXPECT_LT(ownClosureNoiseScale(t.ownRevisits(30), t.odometry, t.poses), 1.0);
  EXPECT_EQ(ownClosureNoiseScale(t.ownRevisits(3), t.odometry, t.poses), 1.0);  // too few
  std::vector<FactorPtr> off = t.ownRevisits(30);  // each 1 rad off: worse than stated
  for (FactorPtr& f : off)
    f = std::make_shared<BetweenFactorSE2>(
        f->key(0), f->key(1),
        static_cast<const BetweenFactorSE2&>(*f).measured() * SE2(0, 0, f->key(0) % 2 ? 1 : -1),
        t.info, FactorRole::LoopClosure);
  EXPECT_EQ(ownClosureNoiseScale(off, t.odometry, t.poses), 1.0);
}

}  // namespace
}  // namespace loopd::server
