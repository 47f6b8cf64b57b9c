// Frame alignment from shared landmarks (server/frame_alignment.h): exact recovery of known
// SE(2)/SE(3) transforms (rotations near π included), least-squares optimality under noise,
// and std::nullopt when the correspondences do not fix the transform.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "server/frame_alignment.h"
#include "tests/solvers/geometry/matrix_forms.h"

namespace loopd::server {
namespace {

using test::randomUnit;

std::vector<PointPair2> pairsFrom(const SE2& M, const std::vector<Vec2>& inS) {
  std::vector<PointPair2> pairs;
  for (const Vec2& q : inS) pairs.push_back({q, M.transform(q)});
  return pairs;
}

std::vector<PointPair3> pairsFrom(const SE3& M, const std::vector<Vec3>& inS) {
  std::vector<PointPair3> pairs;
  for (const Vec3& q : inS) pairs.push_back({q, M.transform(q)});
  return pairs;
}

std::vector<Vec2> randomPoints2(std::mt19937& rng, int n) {
  std::uniform_real_distribution<double> u(-10.0, 10.0);
  std::vector<Vec2> p;
  for (int i = 0; i < n; ++i) p.emplace_back(u(rng), u(rng));
  return p;
}

std::vector<Vec3> randomPoints3(std::mt19937& rng, int n) {
  std::uniform_real_distribution<double> u(-10.0, 10.0);
  std::vector<Vec3> p;
  for (int i = 0; i < n; ++i) p.emplace_back(u(rng), u(rng), u(rng));
  return p;
}

double cost(const SE2& M, const std::vector<PointPair2>& pairs) {
  double c = 0.0;
  for (const auto& p : pairs) c += (M.transform(p.inS) - p.inR).squaredNorm();
  return c;
}

double cost(const SE3& M, const std::vector<PointPair3>& pairs) {
  double c = 0.0;
  for (const auto& p : pairs) c += (M.transform(p.inS) - p.inR).squaredNorm();
  return c;
}

void expectSE2Near(const SE2& a, const SE2& b, double tol) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(wrapAngle(a.theta - b.theta), 0.0, tol);
}

void expectSE3Near(const SE3& a, const SE3& b, double tol) {
  EXPECT_LT((a.R - b.R).norm(), tol) << "\n" << a.R << "\n" << b.R;
  EXPECT_LT((a.t - b.t).norm(), tol) << a.t.transpose() << " vs " << b.t.transpose();
  EXPECT_NEAR(a.R.determinant(), 1.0, 1e-12);
  EXPECT_LT((a.R.transpose() * a.R - Mat3::Identity()).norm(), 1e-12);
}

// ------------------------------------------------------------------------- exact recovery

TEST(FrameAlignment, RecoversSE2Exactly) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-20.0, 20.0), a(-M_PI, M_PI);
  std::vector<SE2> truths = {SE2(3, -4, M_PI),    SE2(-7, 2, M_PI - 1e-7), SE2(1, 1, -M_PI + 1e-7),
                             SE2(0, 0, 0),        SE2(5, 6, 1e-9),         SE2(-2, 8, 0.5 * M_PI),
                             SE2(100, -300, -2.9)};
  for (int i = 0; i < 10; ++i) truths.emplace_back(u(rng), u(rng), a(rng));
  for (const SE2& M : truths) {
    for (int n : {2, 3, 10}) {
      SCOPED_TRACE("theta " + std::to_string(M.theta) + " n " + std::to_string(n));
      const auto got = alignFrames(pairsFrom(M, randomPoints2(rng, n)));
      ASSERT_TRUE(got.has_value());
      expectSE2Near(*got, M, 1e-9);
    }
  }
}

TEST(FrameAlignment, RecoversSE3Exactly) {
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-20.0, 20.0), a(0.0, M_PI);
  std::vector<SE3> truths = {
      SE3(expSO3(Vec3(0, 0, M_PI)), Vec3(1, 2, 3)),
      SE3(expSO3(randomUnit(rng) * M_PI), Vec3(-4, 0, 2)),
      SE3(expSO3(randomUnit(rng) * (M_PI - 1e-7)), Vec3(0, 5, -1)),
      SE3(expSO3(Vec3(M_PI, 0, 0)), Vec3::Zero()),
      SE3(Mat3::Identity(), Vec3(7, -8, 9)),
      SE3(expSO3(randomUnit(rng) * 1e-9), Vec3(1, 0, 0)),
  };
  for (int i = 0; i < 10; ++i)
    truths.emplace_back(expSO3(randomUnit(rng) * a(rng)), Vec3(u(rng), u(rng), u(rng)));
  for (const SE3& M : truths) {
    for (int n : {3, 4, 12}) {
      SCOPED_TRACE("n " + std::to_string(n));
      const auto got = alignFrames(pairsFrom(M, randomPoints3(rng, n)));
      ASSERT_TRUE(got.has_value());
      expectSE3Near(*got, M, 1e-9);
    }
    // Coplanar landmarks (a flat floor) still fix a rigid transform: no reflection.
    std::vector<Vec3> plane = randomPoints3(rng, 6);
    for (Vec3& p : plane) p.z() = 1.5;
    const auto got = alignFrames(pairsFrom(M, plane));
    ASSERT_TRUE(got.has_value());
    expectSE3Near(*got, M, 1e-9);
  }
}

TEST(FrameAlignment, RepeatSightingsOfALandmarkAreJustPoints) {
  std::mt19937 rng(3);
  const SE2 M2(2, -1, 2.5);
  std::vector<Vec2> q2 = randomPoints2(rng, 3);
  q2.push_back(q2[0]);
  q2.push_back(q2[0]);
  q2.push_back(q2[1]);
  const auto got2 = alignFrames(pairsFrom(M2, q2));
  ASSERT_TRUE(got2.has_value());
  expectSE2Near(*got2, M2, 1e-9);

  const SE3 M3(expSO3(Vec3(0.3, -2.0, 1.1)), Vec3(4, 5, -6));
  std::vector<Vec3> q3 = randomPoints3(rng, 3);
  q3.push_back(q3[2]);
  q3.push_back(q3[2]);
  const auto got3 = alignFrames(pairsFrom(M3, q3));
  ASSERT_TRUE(got3.has_value());
  expectSE3Near(*got3, M3, 1e-9);
}

// ------------------------------------------------------------------------- least squares

TEST(FrameAlignment, SE2IsTheLeastSquaresOptimumUnderNoise) {
  std::mt19937 rng(4);
  std::normal_distribution<double> noise(0.0, 0.05), step(0.0, 1e-3);
  for (int trial = 0; trial < 10; ++trial) {
    const SE2 M(3.0 * trial - 10.0, 2.0, -3.0 + 0.6 * trial);
    auto pairs = pairsFrom(M, randomPoints2(rng, 30));
    for (auto& p : pairs) p.inR += Vec2(noise(rng), noise(rng));
    const auto got = alignFrames(pairs);
    ASSERT_TRUE(got.has_value());
    expectSE2Near(*got, M, 0.1);
    const double best = cost(*got, pairs);
    EXPECT_LE(best, cost(M, pairs));
    // No nearby transform does better: a stationary point and a minimum.
    for (int k = 0; k < 50; ++k) {
      const SE2 nearby = got->retract(Eigen::Vector3d(step(rng), step(rng), step(rng)));
      EXPECT_GE(cost(nearby, pairs), best - 1e-12);
    }
  }
}

TEST(FrameAlignment, SE3IsTheLeastSquaresOptimumUnderNoise) {
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.05), step(0.0, 1e-3);
  std::uniform_real_distribution<double> a(0.0, M_PI);
  for (int trial = 0; trial < 10; ++trial) {
    const SE3 M(expSO3(randomUnit(rng) * a(rng)), Vec3(trial, -2.0 * trial, 3.0));
    auto pairs = pairsFrom(M, randomPoints3(rng, 30));
    for (auto& p : pairs) p.inR += Vec3(noise(rng), noise(rng), noise(rng));
    const auto got = alignFrames(pairs);
    ASSERT_TRUE(got.has_value());
    expectSE3Near(*got, M, 0.1);
    const double best = cost(*got, pairs);
    EXPECT_LE(best, cost(M, pairs));
    for (int k = 0; k < 50; ++k) {
      Vec6 d;
      for (int i = 0; i < 6; ++i) d[i] = step(rng);
      EXPECT_GE(cost(got->retract(d), pairs), best - 1e-12);
    }
  }
}

// ------------------------------------------------------------------------- underdetermined

TEST(FrameAlignment, SE2NeedsTwoDistinctPoints) {
  EXPECT_FALSE(alignFrames(std::vector<PointPair2>{}).has_value());
  EXPECT_FALSE(alignFrames(std::vector<PointPair2>{{Vec2(1, 2), Vec2(3, 4)}}).has_value());
  // Two (or more) sightings of one landmark: the rotation about it is free.
  EXPECT_FALSE(
      alignFrames(std::vector<PointPair2>{{Vec2(1, 2), Vec2(3, 4)}, {Vec2(1, 2), Vec2(3, 4)}})
          .has_value());
  EXPECT_FALSE(alignFrames(std::vector<PointPair2>{{Vec2(1, 2), Vec2(3, 4)},
                                                   {Vec2(1, 2), Vec2(3.1, 4)},
                                                   {Vec2(1, 2), Vec2(2.9, 4.2)}})
                   .has_value());
  // Far from the origin, the same landmark is still one point.
  EXPECT_FALSE(alignFrames(std::vector<PointPair2>{{Vec2(1e6, -1e6), Vec2(0, 0)},
                                                   {Vec2(1e6, -1e6), Vec2(1, 0)}})
                   .has_value());
  // Non-finite input.
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(
      alignFrames(std::vector<PointPair2>{{Vec2(0, 0), Vec2(0, 0)}, {Vec2(1, 0), Vec2(nan, 0)}})
          .has_value());
  // Two distinct points suffice.
  const auto got =
      alignFrames(std::vector<PointPair2>{{Vec2(0, 0), Vec2(5, 5)}, {Vec2(1, 0), Vec2(5, 6)}});
  ASSERT_TRUE(got.has_value());
  expectSE2Near(*got, SE2(5, 5, 0.5 * M_PI), 1e-12);
}

TEST(FrameAlignment, SE3NeedsThreeNonCollinearPoints) {
  EXPECT_FALSE(alignFrames(std::vector<PointPair3>{}).has_value());
  EXPECT_FALSE(alignFrames(std::vector<PointPair3>{{Vec3(1, 2, 3), Vec3(0, 0, 0)}}).has_value());
  EXPECT_FALSE(alignFrames(std::vector<PointPair3>{{Vec3(1, 2, 3), Vec3(0, 0, 0)},
                                                   {Vec3(4, 5, 6), Vec3(1, 1, 1)}})
                   .has_value());
  // Collinear landmarks leave the rotation about their line free, however many.
  const SE3 M(expSO3(Vec3(0.2, 1.0, -0.4)), Vec3(1, 2, 3));
  std::vector<Vec3> line;
  for (int i = 0; i < 8; ++i) line.push_back(Vec3(1, -2, 0.5) + 0.7 * i * Vec3(3, 1, -2));
  EXPECT_FALSE(alignFrames(pairsFrom(M, line)).has_value());
  // Three sightings of one landmark, or of two.
  EXPECT_FALSE(
      alignFrames(pairsFrom(M, {Vec3(1, 1, 1), Vec3(1, 1, 1), Vec3(1, 1, 1)})).has_value());
  EXPECT_FALSE(
      alignFrames(pairsFrom(M, {Vec3(1, 1, 1), Vec3(2, 0, 1), Vec3(1, 1, 1)})).has_value());
  const double inf = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(alignFrames(std::vector<PointPair3>{{Vec3(0, 0, 0), Vec3(0, 0, 0)},
                                                   {Vec3(1, 0, 0), Vec3(1, 0, 0)},
                                                   {Vec3(0, 1, 0), Vec3(0, inf, 0)}})
                   .has_value());
  // Three non-collinear points suffice.
  const auto got = alignFrames(pairsFrom(M, {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)}));
  ASSERT_TRUE(got.has_value());
  expectSE3Near(*got, M, 1e-12);
}

}  // namespace
}  // namespace loopd::server
