// landmarkAidedHeadings2D and the orientation-first start on graphs with landmark sightings:
// headings that odometry alone dead-reckons are corrected by re-sighted landmarks.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <stdexcept>
#include <vector>

#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/landmark_factors.h"
#include "solvers/init/initialization.h"
#include "solvers/init/landmark_headings.h"

namespace loopd {
namespace {

// Two laps of a circle (radius 10 m, 60 poses a lap) among 8 landmarks; every landmark
// within 9 m is sighted (exactly). Odometry translations are exact; each odometry heading
// change is off by `headingBias`, so dead reckoning turns 120·bias too far by the end.
struct Scene {
  FactorGraph graph;
  Values guess;  // poses by composing odometry, landmarks at the origin
  std::vector<SE2> truth;
};

constexpr int kPoses = 120;

Scene circleAmongLandmarks(double headingBias, double anchorHeading) {
  Scene s;
  for (int n = 0; n < kPoses; ++n) {
    const double phi = 2.0 * M_PI * n / 60.0;
    const Vec2 t = rot2(anchorHeading) * Vec2(10.0 * std::cos(phi), 10.0 * std::sin(phi));
    s.truth.emplace_back(t.x(), t.y(), wrapAngle(phi + M_PI / 2 + anchorHeading));
  }
  const std::vector<Vec2> landmarks = {{0, 0},  {3, 4},   {-4, 2},  {2, -5},
                                       {14, 0}, {0, -14}, {-14, 3}, {5, 13}};
  Eigen::Matrix3d odometryInfo = Eigen::Matrix3d::Zero();
  odometryInfo.diagonal() << 400.0, 400.0, 1e4;
  const Mat2 sightingInfo = 100.0 * Mat2::Identity();
  s.guess.insert(poseKey(0), s.truth[0]);
  for (int n = 0; n + 1 < kPoses; ++n) {
    SE2 z = s.truth[n].inverse() * s.truth[n + 1];
    z.theta += headingBias;
    s.graph.add(std::make_shared<BetweenFactorSE2>(poseKey(n), poseKey(n + 1), z, odometryInfo,
                                                   FactorRole::Odometry));
    s.guess.insert(poseKey(n + 1), s.guess.se2(s.guess.slot(poseKey(n))) * z);
  }
  for (int n = 0; n < kPoses; ++n)
    for (int k = 0; k < static_cast<int>(landmarks.size()); ++k) {
      const Vec2 p = rot2(anchorHeading) * landmarks[k];
      const Vec2 local = s.truth[n].R().transpose() * (p - s.truth[n].t());
      if (local.norm() < 9.0)
        s.graph.add(
            std::make_shared<PosePointFactor2>(poseKey(n), landmarkKey(k), local, sightingInfo));
    }
  for (int k = 0; k < static_cast<int>(landmarks.size()); ++k)
    s.guess.insertPoint2(landmarkKey(k), Vec2::Zero());
  return s;
}

// Largest heading error of the poses in `headings` (per slot of s.guess).
double worstHeadingError(const Scene& s, const std::vector<double>& headings) {
  double worst = 0.0;
  for (int n = 0; n < kPoses; ++n)
    worst =
        std::max(worst, std::abs(wrapAngle(headings[s.guess.slot(poseKey(n))] - s.truth[n].theta)));
  return worst;
}

std::vector<double> guessedHeadings(const Values& v) {
  std::vector<double> theta(v.size(), 0.0);
  for (int s = 0; s < v.size(); ++s)
    if (v.type(s) == VarType::SE2) theta[s] = v.se2(s).theta;
  return theta;
}

TEST(LandmarkAidedHeadings, ExactOnNoiseFreeSightings) {
  // The anchor's heading is not 0: its known (cos, sin) enters the right-hand side.
  const Scene s = circleAmongLandmarks(0.0, 2.5);
  ASSERT_TRUE(hasPointSightings2D(s.graph));
  // Weight headings far off: they only rotate the weights, so the solution stays exact.
  std::vector<double> weights = guessedHeadings(s.guess);
  for (double& w : weights) w += 0.3;
  const std::vector<double> theta =
      landmarkAidedHeadings2D(s.graph, s.guess, s.guess.slot(poseKey(0)), weights);
  EXPECT_LT(worstHeadingError(s, theta), 1e-9);
}

TEST(LandmarkAidedHeadings, CorrectDeadReckonedDrift) {
  const Scene s = circleAmongLandmarks(0.01, 0.0);
  const std::vector<double> deadReckoned = guessedHeadings(s.guess);
  ASSERT_GT(worstHeadingError(s, deadReckoned), 1.0);  // 119 steps of 0.01 rad
  const std::vector<double> theta =
      landmarkAidedHeadings2D(s.graph, s.guess, s.guess.slot(poseKey(0)), deadReckoned);
  EXPECT_LT(worstHeadingError(s, theta), 0.05);
}

TEST(LandmarkAidedHeadings, OrientationFirstStartUsesTheSightings) {
  // Without the sightings' headings the start keeps the odometry's 1.2 rad of drift.
  const Scene s = circleAmongLandmarks(0.01, 0.0);
  const Values start = initializeOrientationFirst2D(s.graph, s.guess, poseKey(0));
  EXPECT_LT(worstHeadingError(s, guessedHeadings(start)), 0.05);
  double worstPosition = 0.0;
  for (int n = 0; n < kPoses; ++n)
    worstPosition =
        std::max(worstPosition, (start.se2(start.slot(poseKey(n))).t() - s.truth[n].t()).norm());
  EXPECT_LT(worstPosition, 0.5);
}

TEST(LandmarkAidedHeadings, APoseHeldByOneSightingKeepsTheOdometryHeadings) {
  // Pose 500 has no odometry and one sighting: its heading is free in the relaxation, which
  // refuses the graph; the start keeps the between factors' headings and places the pose.
  Scene s = circleAmongLandmarks(0.0, 0.0);
  const Vec2 seen(1.0, 2.0);
  s.graph.add(std::make_shared<PosePointFactor2>(poseKey(500), landmarkKey(1), seen,
                                                 100.0 * Mat2::Identity()));
  s.guess.insert(poseKey(500), SE2(5.0, 5.0, 0.7));
  EXPECT_THROW(
      landmarkAidedHeadings2D(s.graph, s.guess, s.guess.slot(poseKey(0)), guessedHeadings(s.guess)),
      std::runtime_error);
  const Values start = initializeOrientationFirst2D(s.graph, s.guess, poseKey(0));
  const SE2 lone = start.se2(start.slot(poseKey(500)));
  EXPECT_DOUBLE_EQ(lone.theta, 0.7);
  EXPECT_LT((lone.transform(seen) - start.point2(start.slot(landmarkKey(1)))).norm(), 1e-9);
  EXPECT_LT(worstHeadingError(s, guessedHeadings(start)), 1e-9);
}

TEST(LandmarkAidedHeadings, PoseGraphsHaveNoSightings) {
  Scene s = circleAmongLandmarks(0.0, 0.0);
  FactorGraph odometryOnly;
  for (const auto& f : s.graph.factors())
    if (f->role() == FactorRole::Odometry) odometryOnly.add(f);
  EXPECT_FALSE(hasPointSightings2D(odometryOnly));
}

}  // namespace
}  // namespace loopd
