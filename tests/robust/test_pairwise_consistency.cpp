// The pairwise-consistency (PCM) selection: on a noisy trajectory that circles a square three
// times, the true revisits form one mutually consistent set and wrong closures do not join
// it, in 2D and 3D; the scales and the short-cycle calibration set the test's width; a pair
// is judged exactly at the gate; a closure nothing agrees with stays out; closures between two
// robots, through their anchors and in either direction, are judged as one robot's.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <random>
#include <stdexcept>

#include "robust/pairwise_consistency.h"
#include "robust/robust_factors.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/geometry/so3.h"
#include "tests/robust/square_walk.h"
#include "tests/solvers/init/two_robot_split.h"

namespace loopd {
namespace {

using square::kLap;
using square::walk;

SE3 lift(const SE2& x) { return SE3(expSO3(Vec3(0, 0, x.theta)), Vec3(x.x, x.y, 0.0)); }

struct Scenario {
  FactorGraph graph;
  Values odometry;  // the odometry measurements composed
  std::vector<int> trueClosures, wrongClosures;
};

// The measurement noise drawn (σ_t, σ_r per axis, times `noise`), the information stated
// (for σ 0.1 m, 0.01 rad) and how far off the wrong closures are (times `wrongScale`: 2–4 m,
// 0.5–1 rad).
struct WalkSetup {
  bool in3d = false;
  int wrong = 30;
  double noise = 1.0;       // drawn σ = noise × (0.1 m, 0.01 rad)
  double wrongScale = 1.0;  // wrong closures' error × this
  unsigned seed = 7;
};

// Three laps of the square; odometry and closures measured with noise; closures from lap 3
// back to laps 1 and 2 at the same spot (true) and `wrong` random pairs measured off their
// true relative pose.
Scenario square(const WalkSetup& setup) {
  Scenario s;
  const int n = 3 * kLap;
  std::mt19937 rng(setup.seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  auto noisy = [&](const SE2& z) {
    return z * SE2(0.1 * setup.noise * gauss(rng), 0.1 * setup.noise * gauss(rng),
                   0.01 * setup.noise * gauss(rng));
  };
  auto between = [&](int i, int j, const SE2& z, FactorRole role) {
    if (setup.in3d) {
      Mat6 information = Mat6::Identity() * 100.0;
      information.bottomRightCorner<3, 3>() *= 100.0;
      s.graph.add(
          std::make_shared<BetweenFactorSE3>(poseKey(i), poseKey(j), lift(z), information, role));
    } else {
      const Eigen::Matrix3d information = Eigen::Vector3d(100.0, 100.0, 1e4).asDiagonal();
      s.graph.add(std::make_shared<BetweenFactorSE2>(poseKey(i), poseKey(j), z, information, role));
    }
  };
  SE2 composed;
  for (int i = 0; i < n; ++i) {
    if (i > 0) {
      const SE2 z = noisy(walk(i - 1).between(walk(i)));
      between(i - 1, i, z, FactorRole::Odometry);
      composed = composed * z;
    }
    if (setup.in3d)
      s.odometry.insert(poseKey(i), lift(composed));
    else
      s.odometry.insert(poseKey(i), composed);
  }
  for (int i = 2 * kLap; i < n; i += 3) {
    s.trueClosures.push_back(s.graph.size());
    between(i - kLap, i, noisy(SE2()), FactorRole::LoopClosure);
    s.trueClosures.push_back(s.graph.size());
    between(i - 2 * kLap, i, noisy(SE2()), FactorRole::LoopClosure);
  }
  std::uniform_int_distribution<int> pose(0, n - 1);
  auto sign = [&] { return u(rng) < 0.5 ? -1.0 : 1.0; };
  for (int k = 0; k < setup.wrong; ++k) {
    int a = pose(rng), b = pose(rng);
    if (std::abs(a - b) < 2) b = (a + 5) % n;
    const double heading = 2.0 * M_PI * u(rng), off = setup.wrongScale * (2.0 + 2.0 * u(rng));
    const SE2 error(off * std::cos(heading), off * std::sin(heading),
                    setup.wrongScale * sign() * (0.5 + 0.5 * u(rng)));
    s.wrongClosures.push_back(s.graph.size());
    between(a, b, walk(a).between(walk(b)) * error, FactorRole::LoopClosure);
  }
  return s;
}

int wrongIn(const Scenario& s, const ConsistentSet& set) {
  int in = 0;
  for (int i : s.wrongClosures) in += set.member[i];
  return in;
}

void expectTrueSetFound(bool in3d) {
  WalkSetup setup;
  setup.in3d = in3d;
  const Scenario s = square(setup);
  const ConsistentSet set = pairwiseConsistentClosures(s.graph, s.odometry);
  EXPECT_EQ(set.judged, static_cast<int>(s.trueClosures.size() + s.wrongClosures.size()));
  for (int i : s.trueClosures) EXPECT_TRUE(set.member[i]) << "true closure " << i;
  EXPECT_EQ(wrongIn(s, set), 0);
  EXPECT_EQ(set.size, static_cast<int>(s.trueClosures.size()));
  for (int i = 0; i < s.graph.size(); ++i)
    if (s.graph[i]->role() == FactorRole::Odometry) EXPECT_FALSE(set.member[i]);
}

TEST(PairwiseConsistency, KeepsTheTrueRevisitsAndNoWrongClosure2D) { expectTrueSetFound(false); }

TEST(PairwiseConsistency, KeepsTheTrueRevisitsAndNoWrongClosure3D) { expectTrueSetFound(true); }

// The checkpoint (GncOptions::interrupt) is called once per judged closure, before its row of
// pair tests, leaves the set as it is when it returns, and gives the test up when it throws.
TEST(PairwiseConsistency, CallsItsCheckpointPerClosureAndIsGivenUpByIt) {
  const Scenario s = square(WalkSetup{});
  const ConsistentSet plain = pairwiseConsistentClosures(s.graph, s.odometry);
  ConsistencyOptions o;
  int calls = 0;
  o.checkpoint = [&] { ++calls; };
  const ConsistentSet watched = pairwiseConsistentClosures(s.graph, s.odometry, o);
  EXPECT_EQ(calls, plain.judged);
  EXPECT_EQ(watched.member, plain.member);
  calls = 0;
  o.checkpoint = [&] {
    if (++calls == 3) throw std::runtime_error("given up");
  };
  EXPECT_THROW(pairwiseConsistentClosures(s.graph, s.odometry, o), std::runtime_error);
  EXPECT_EQ(calls, 3);
}

// The stated uncertainty decides: a closure 1.5 m off is inconsistent with the revisits near
// it under the stated information, and joins them once odometry and closures are declared
// 100× noisier (the scales the solver passes when the information is miscalibrated).
TEST(PairwiseConsistency, ScalesWidenTheTest) {
  WalkSetup setup;
  setup.wrong = 0;
  Scenario s = square(setup);
  const int offset = s.graph.size();
  s.graph.add(std::make_shared<BetweenFactorSE2>(
      poseKey(kLap + 5), poseKey(2 * kLap + 5), SE2(1.5, 0.0, 0.0),
      Eigen::Vector3d(100.0, 100.0, 1e4).asDiagonal(), FactorRole::LoopClosure));
  ConsistencyOptions stated;
  stated.calibrationWindow = 0;  // the scales alone
  EXPECT_FALSE(pairwiseConsistentClosures(s.graph, s.odometry, stated).member[offset]);
  ConsistencyOptions loose = stated;
  loose.odometryScale = 100.0;
  loose.closureScale = 100.0;
  EXPECT_TRUE(pairwiseConsistentClosures(s.graph, s.odometry, loose).member[offset]);
}

// Under-confident information (the noise 100× smaller than stated, as on parking-garage):
// closures 6–12 cm off pass the stated test, and the short-cycle calibration finds the factor
// (about 10⁻⁴) and keeps them out. Both halves are checked.
TEST(PairwiseConsistency, ShortCyclesCalibrateUnderConfidentInformation) {
  WalkSetup setup;
  setup.noise = 0.01;
  setup.wrongScale = 0.03;
  const Scenario s = square(setup);
  ConsistencyOptions uncalibrated;
  uncalibrated.calibrationWindow = 0;
  EXPECT_GT(wrongIn(s, pairwiseConsistentClosures(s.graph, s.odometry, uncalibrated)), 10);
  const ConsistentSet set = pairwiseConsistentClosures(s.graph, s.odometry);
  EXPECT_GE(set.calibrationPairs, 30);
  EXPECT_LT(set.calibration, 1e-3);
  EXPECT_GT(set.calibration, 1e-5);
  EXPECT_EQ(wrongIn(s, set), 0);
  int trueIn = 0;
  for (int i : s.trueClosures) trueIn += set.member[i];
  EXPECT_GE(trueIn, static_cast<int>(0.9 * s.trueClosures.size()));

  // The calibration alone (the frame-join test's, server/closure_agreement.h): the same
  // factor from the same short cycles, no set.
  ConsistencyOptions only;
  only.calibrationOnly = true;
  const ConsistentSet calibrated = pairwiseConsistentClosures(s.graph, s.odometry, only);
  EXPECT_EQ(calibrated.calibration, set.calibration);
  EXPECT_EQ(calibrated.calibrationPairs, set.calibrationPairs);
  EXPECT_EQ(calibrated.size, 0);
  for (char m : calibrated.member) EXPECT_EQ(m, 0);
}

// Two closures with the same ends (poses 0 and 2, at one place, so no lever arm and no chain
// between them): the cycle is z_j⁻¹·z_i, and the statistic is d²/(σ_t,i² + σ_t,j²) for a
// translation d apart and θ²/(σ_r,i² + σ_r,j²) for a rotation θ apart. Within a millionth
// below the χ²₃(0.999) gate they agree, above it they do not, either way (each term is
// checked alone first, the rotation's with sin θ before the atan2).
TEST(PairwiseConsistency, JudgesAPairAtTheGateByTranslationAndByRotation) {
  const Eigen::Matrix3d information = Eigen::Vector3d(100.0, 100.0, 1e4).asDiagonal();
  const double gate = chi2Quantile(3, 0.999);
  const double dGate = std::sqrt(gate * 2.0 * 0.01), thetaGate = std::sqrt(gate * 2.0 * 1e-4);
  auto pairSize = [&](const SE2& apart) {
    FactorGraph g;
    Values odometry;
    odometry.insert(poseKey(0), SE2());
    odometry.insert(poseKey(1), SE2(1.0, 0.0, 0.0));
    odometry.insert(poseKey(2), SE2());
    g.add(std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(1), SE2(1.0, 0.0, 0.0),
                                             information, FactorRole::Odometry));
    g.add(std::make_shared<BetweenFactorSE2>(poseKey(1), poseKey(2), SE2(-1.0, 0.0, 0.0),
                                             information, FactorRole::Odometry));
    g.add(std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(2), SE2(), information,
                                             FactorRole::LoopClosure));
    g.add(std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(2), apart, information,
                                             FactorRole::LoopClosure));
    ConsistencyOptions o;
    o.calibrationWindow = 0;
    return pairwiseConsistentClosures(g, odometry, o).size;
  };
  EXPECT_EQ(pairSize(SE2(dGate * (1.0 - 1e-6), 0.0, 0.0)), 2);
  EXPECT_EQ(pairSize(SE2(dGate * (1.0 + 1e-6), 0.0, 0.0)), 1);
  EXPECT_EQ(pairSize(SE2(0.0, 0.0, thetaGate * (1.0 - 1e-6))), 2);
  EXPECT_EQ(pairSize(SE2(0.0, 0.0, thetaGate * (1.0 + 1e-6))), 1);
  EXPECT_EQ(pairSize(SE2(0.0, 0.0, 1.0)), 1);  // far out: sin θ alone settles it
}

// A closure to a pose off the chain (a second robot's, without odometry) has no partner to
// agree with: judged, but not in the set.
TEST(PairwiseConsistency, LeavesOutAClosureNothingAgreesWith) {
  WalkSetup setup;
  setup.wrong = 0;
  Scenario s = square(setup);
  s.odometry.insert(poseKey(0, 1), SE2());
  const int other = s.graph.size();
  s.graph.add(std::make_shared<BetweenFactorSE2>(
      poseKey(3), poseKey(0, 1), SE2(), Eigen::Matrix3d::Identity(), FactorRole::LoopClosure));
  const ConsistentSet set = pairwiseConsistentClosures(s.graph, s.odometry);
  EXPECT_EQ(set.judged, static_cast<int>(s.trueClosures.size()) + 1);
  EXPECT_FALSE(set.member[other]);
  EXPECT_EQ(set.size, static_cast<int>(s.trueClosures.size()));
}

// A break in the odometry (as between two robots' chains) leaves pairs across it unjudged:
// without unjudgedPairsAgree the set holds the closures of one side alone; with it, the true
// closures of both, and a wrong one inside a side still stays out.
TEST(PairwiseConsistency, UnjudgedPairsAgreeOnlyWhenAsked) {
  WalkSetup setup;
  setup.wrong = 0;
  Scenario s = square(setup);
  const int breakAt = 2 * kLap + kLap / 2;  // in lap 3: its closures fall on both sides
  FactorGraph cut;
  std::vector<int> index(static_cast<size_t>(s.graph.size()), -1);
  for (int i = 0; i < s.graph.size(); ++i) {
    const Factor& f = *s.graph[i];
    if (f.role() == FactorRole::Odometry &&
        keyIndex(f.key(1)) == static_cast<std::uint64_t>(breakAt))
      continue;
    index[static_cast<size_t>(i)] = cut.size();
    cut.add(s.graph[i]);
  }
  const int wrong = cut.size();
  cut.add(std::make_shared<BetweenFactorSE2>(poseKey(5), poseKey(30), SE2(3, -2, 0.8),
                                             Eigen::Vector3d(100.0, 100.0, 1e4).asDiagonal(),
                                             FactorRole::LoopClosure));
  const int trueCount = static_cast<int>(s.trueClosures.size());
  const ConsistentSet strict = pairwiseConsistentClosures(cut, s.odometry);
  EXPECT_GT(strict.size, 0);
  EXPECT_LT(strict.size, trueCount);
  ConsistencyOptions o;
  o.unjudgedPairsAgree = true;
  const ConsistentSet both = pairwiseConsistentClosures(cut, s.odometry, o);
  EXPECT_EQ(both.size, trueCount);
  for (int i : s.trueClosures)
    EXPECT_TRUE(both.member[static_cast<size_t>(index[static_cast<size_t>(i)])]) << i;
  EXPECT_FALSE(both.member[static_cast<size_t>(wrong)]);
}

// The walk's third lap as a second robot (anchored, in its own frame): every true closure is
// now between the robots, through their anchors. With the odometry step across the split
// (trusted, anchored too) the set is the one-robot walk's. Anchored closures were not judged
// before, so none of them was in the set.
TEST(PairwiseConsistency, JudgesClosuresBetweenRobotsThroughTheirAnchors) {
  const Scenario s = square(WalkSetup{});
  const ConsistentSet one = pairwiseConsistentClosures(s.graph, s.odometry);
  const std::uint64_t at = 2 * kLap;
  const test::TwoRobotSplit split =
      test::splitInTwo(s.graph, s.odometry, at, s.odometry.se2(s.odometry.slot(poseKey(at))));
  ASSERT_EQ(split.graph.size(), s.graph.size());
  const ConsistentSet two = pairwiseConsistentClosures(split.graph, split.values);
  EXPECT_EQ(two.judged, one.judged);
  EXPECT_EQ(two.size, one.size);
  for (int i : s.trueClosures) EXPECT_TRUE(two.member[static_cast<size_t>(i)]) << i;
  EXPECT_EQ(wrongIn(s, two), 0);
}

// Two robots' chains with nothing trusted between them, and their closures sent from either
// robot (every other one from robot 1, as the inverse measurement): the closures between the
// same two chains still pair up, so the true ones make the set.
TEST(PairwiseConsistency, PairsClosuresBetweenRobotsWhicheverWayTheyPoint) {
  const Scenario s = square(WalkSetup{});
  const std::uint64_t at = 2 * kLap;
  const test::TwoRobotSplit split =
      test::splitInTwo(s.graph, s.odometry, at, s.odometry.se2(s.odometry.slot(poseKey(at))));
  FactorGraph apart;
  std::vector<int> index(static_cast<size_t>(split.graph.size()), -1);
  bool flip = false;
  for (int i = 0; i < split.graph.size(); ++i) {
    const FactorPtr& f = split.graph[i];
    const auto* a = dynamic_cast<const AnchoredBetweenFactorSE2*>(f.get());
    if (a && f->role() == FactorRole::Odometry) continue;  // the step across the split
    index[static_cast<size_t>(i)] = apart.size();
    if (a && (flip = !flip))
      apart.add(std::make_shared<AnchoredBetweenFactorSE2>(f->key(2), f->key(3), f->key(0),
                                                           f->key(1), a->measured().inverse(),
                                                           a->information(), f->role()));
    else
      apart.add(f);
  }
  const ConsistentSet set = pairwiseConsistentClosures(apart, split.values);
  EXPECT_EQ(set.size, static_cast<int>(s.trueClosures.size()));
  for (int i : s.trueClosures)
    EXPECT_TRUE(set.member[static_cast<size_t>(index[static_cast<size_t>(i)])]) << i;
}

}  // namespace
}  // namespace loopd
