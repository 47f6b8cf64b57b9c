// Anchored landmark sightings (server/anchored_sighting_factor.h): the residual against the
// plain landmark factor at the sighting pose in the landmark owner's frame and, independently,
// at the common-frame pose and point; all four Jacobian blocks against central differences
// taken through Values::retract (right perturbations for poses, additive for points); clone().
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <limits>
#include <memory>
#include <random>
#include <string>

#include "server/anchored_sighting_factor.h"
#include "solvers/factors/landmark_factors.h"
#include "tests/solvers/factors/jacobian_check.h"
#include "tests/solvers/geometry/matrix_forms.h"

namespace loopd::server {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;
using test::randomInformation;
using test::randomUnit;

const Key kAr = makeKey(0, KeyKind::Anchor, 0);
const Key kXr = poseKey(7, 0);
const Key kAs = makeKey(1, KeyKind::Anchor, 0);
const Key kLs = landmarkKey(3, 1);

// An angle of magnitude in [0.4, 2.9], either sign: far from 0 and from ±π.
double randomAngle(std::mt19937& rng) {
  std::uniform_real_distribution<double> mag(0.4, 2.9);
  std::bernoulli_distribution neg(0.5);
  const double a = mag(rng);
  return neg(rng) ? -a : a;
}

SE2 randomSE2(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-4.0, 4.0);
  return {u(rng), u(rng), randomAngle(rng)};
}

SE3 randomSE3(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-4.0, 4.0), a(0.4, 2.9);
  return {expSO3(randomUnit(rng) * a(rng)), Vec3(u(rng), u(rng), u(rng))};
}

Vec2 randomPoint2(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-6.0, 6.0);
  return {u(rng), u(rng)};
}

Vec3 randomPoint3(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-6.0, 6.0);
  return {u(rng), u(rng), u(rng)};
}

// Values for the four keys.
Values values2(const SE2& Ar, const SE2& xr, const SE2& As, const Vec2& l) {
  Values v;
  v.insert(kAr, Ar);
  v.insert(kXr, xr);
  v.insert(kAs, As);
  v.insertPoint2(kLs, l);
  return v;
}

Values values3(const SE3& Ar, const SE3& xr, const SE3& As, const Vec3& l) {
  Values v;
  v.insert(kAr, Ar);
  v.insert(kXr, xr);
  v.insert(kAs, As);
  v.insertPoint3(kLs, l);
  return v;
}

// Values of a plain two-key factor (pose, point).
template <class Pose, class Point>
Values plainValues(const Pose& pose, const Point& point) {
  Values v;
  v.insert(poseKey(0), pose);
  if constexpr (Point::RowsAtCompileTime == 2)
    v.insertPoint2(landmarkKey(0), point);
  else
    v.insertPoint3(landmarkKey(0), point);
  return v;
}

void expectVectorsNear(const VectorXd& a, const VectorXd& b, double tol, const std::string& what) {
  ASSERT_EQ(a.size(), b.size()) << what;
  EXPECT_LT((a - b).norm(), tol * (1.0 + b.norm())) << what << "\n"
                                                    << a.transpose() << "\n"
                                                    << b.transpose();
}

// --------------------------------------------------------------------- residual vs plain

TEST(AnchoredSightingFactor, PosePoint2EqualsPlainFactorInOwnerAndCommonFrames) {
  std::mt19937 rng(11);
  for (int trial = 0; trial < 20; ++trial) {
    const SE2 Ar = randomSE2(rng), xr = randomSE2(rng), As = randomSE2(rng);
    const Vec2 l = randomPoint2(rng), z = randomPoint2(rng);
    const Eigen::Matrix2d info = randomInformation<2>(rng);
    const AnchoredPosePointFactor2 f(kAr, kXr, kAs, kLs, z, info);
    const PosePointFactor2 g(poseKey(0), landmarkKey(0), z, info);
    const VectorXd e = f.whitenedError(values2(Ar, xr, As, l));
    expectVectorsNear(e, g.whitenedError(plainValues(As.inverse() * Ar * xr, l)), 1e-9, "owner");
    expectVectorsNear(e, g.whitenedError(plainValues(Ar * xr, As.transform(l))), 1e-9, "common");
  }
  // At the true measurement the residual vanishes: z = landmark in the sighting pose's frame.
  const SE2 Ar(1, 2, 0.7), xr(-2, 0.5, 2.1), As(3, -1, -1.9);
  const Vec2 l(4, -3);
  const Vec2 z = (Ar * xr).transformTo(As.transform(l));
  const AnchoredPosePointFactor2 f(kAr, kXr, kAs, kLs, z, Eigen::Matrix2d::Identity());
  EXPECT_LT(f.chi2(values2(Ar, xr, As, l)), 1e-20);
  EXPECT_GT(f.chi2(values2(Ar, xr, As, Vec2(l + Vec2(0.1, 0)))), 1e-3);
}

TEST(AnchoredSightingFactor, PosePoint3EqualsPlainFactorInOwnerAndCommonFrames) {
  std::mt19937 rng(12);
  for (int trial = 0; trial < 20; ++trial) {
    const SE3 Ar = randomSE3(rng), xr = randomSE3(rng), As = randomSE3(rng);
    const Vec3 l = randomPoint3(rng), z = randomPoint3(rng);
    const Mat3 info = randomInformation<3>(rng);
    const AnchoredPosePointFactor3 f(kAr, kXr, kAs, kLs, z, info);
    const PosePointFactor3 g(poseKey(0), landmarkKey(0), z, info);
    const VectorXd e = f.whitenedError(values3(Ar, xr, As, l));
    expectVectorsNear(e, g.whitenedError(plainValues(As.inverse() * Ar * xr, l)), 1e-9, "owner");
    expectVectorsNear(e, g.whitenedError(plainValues(Ar * xr, As.transform(l))), 1e-9, "common");
  }
  std::mt19937 rng2(13);
  const SE3 Ar = randomSE3(rng2), xr = randomSE3(rng2), As = randomSE3(rng2);
  const Vec3 l(1, -2, 3);
  const Vec3 z = (Ar * xr).transformTo(As.transform(l));
  const AnchoredPosePointFactor3 f(kAr, kXr, kAs, kLs, z, Mat3::Identity());
  EXPECT_LT(f.chi2(values3(Ar, xr, As, l)), 1e-20);
  EXPECT_GT(f.chi2(values3(Ar, xr, As, Vec3(l + Vec3(0, 0, 0.1)))), 1e-3);
}

TEST(AnchoredSightingFactor, BearingRange2EqualsPlainFactorInOwnerAndCommonFrames) {
  std::mt19937 rng(14);
  std::normal_distribution<double> noise(0.0, 0.2);
  for (int trial = 0; trial < 20; ++trial) {
    const SE2 Ar = randomSE2(rng), xr = randomSE2(rng), As = randomSE2(rng);
    const Vec2 l = randomPoint2(rng);
    const Vec2 v = (Ar * xr).transformTo(As.transform(l));
    // Near the true (bearing, range), so the wrapped bearing error stays far from ±π.
    const Vec2 z(wrapAngle(std::atan2(v.y(), v.x()) + noise(rng)), v.norm() + noise(rng));
    const Eigen::Matrix2d info = randomInformation<2>(rng);
    const AnchoredBearingRangeFactor2 f(kAr, kXr, kAs, kLs, z, info);
    const BearingRangeFactor2 g(poseKey(0), landmarkKey(0), z, info);
    const VectorXd e = f.whitenedError(values2(Ar, xr, As, l));
    EXPECT_GT(e.norm(), 1e-6);
    expectVectorsNear(e, g.whitenedError(plainValues(As.inverse() * Ar * xr, l)), 1e-9, "owner");
    expectVectorsNear(e, g.whitenedError(plainValues(Ar * xr, As.transform(l))), 1e-9, "common");
  }
  const SE2 Ar(1, 2, 0.7), xr(-2, 0.5, 2.1), As(3, -1, -1.9);
  const Vec2 l(4, -3);
  const Vec2 v = (Ar * xr).transformTo(As.transform(l));
  const AnchoredBearingRangeFactor2 f(kAr, kXr, kAs, kLs, Vec2(std::atan2(v.y(), v.x()), v.norm()),
                                      Eigen::Matrix2d::Identity());
  EXPECT_LT(f.chi2(values2(Ar, xr, As, l)), 1e-20);
}

// --------------------------------------------------------------------- Jacobians

TEST(AnchoredSightingFactor, PosePoint2JacobiansMatchNumerical) {
  std::mt19937 rng(21);
  for (int trial = 0; trial < 20; ++trial) {
    SCOPED_TRACE("trial " + std::to_string(trial));
    const Values v = values2(randomSE2(rng), randomSE2(rng), randomSE2(rng), randomPoint2(rng));
    const AnchoredPosePointFactor2 f(kAr, kXr, kAs, kLs, randomPoint2(rng),
                                     randomInformation<2>(rng));
    test::checkJacobians(f, v, "", 1e-6, 1e-6, true);
  }
}

TEST(AnchoredSightingFactor, PosePoint3JacobiansMatchNumerical) {
  std::mt19937 rng(22);
  for (int trial = 0; trial < 20; ++trial) {
    SCOPED_TRACE("trial " + std::to_string(trial));
    const Values v = values3(randomSE3(rng), randomSE3(rng), randomSE3(rng), randomPoint3(rng));
    const AnchoredPosePointFactor3 f(kAr, kXr, kAs, kLs, randomPoint3(rng),
                                     randomInformation<3>(rng));
    test::checkJacobians(f, v, "", 1e-6, 1e-6, true);
  }
}

TEST(AnchoredSightingFactor, BearingRange2JacobiansMatchNumerical) {
  std::mt19937 rng(23);
  std::normal_distribution<double> noise(0.0, 0.3);
  for (int trial = 0; trial < 20; ++trial) {
    SCOPED_TRACE("trial " + std::to_string(trial));
    const SE2 Ar = randomSE2(rng), xr = randomSE2(rng), As = randomSE2(rng);
    Vec2 l = randomPoint2(rng);
    Vec2 v = (Ar * xr).transformTo(As.transform(l));
    while (v.norm() < 1.0) {  // keep the landmark off the sighting pose
      l = randomPoint2(rng);
      v = (Ar * xr).transformTo(As.transform(l));
    }
    const Vec2 z(wrapAngle(std::atan2(v.y(), v.x()) + noise(rng)), v.norm() + noise(rng));
    const AnchoredBearingRangeFactor2 f(kAr, kXr, kAs, kLs, z, randomInformation<2>(rng));
    test::checkJacobians(f, values2(Ar, xr, As, l), "", 1e-6, 1e-6, true);
  }
}

// --------------------------------------------------------------------- clone

template <class F>
void expectSameFactor(const F& f, const Factor& c, const Values& v) {
  EXPECT_EQ(c.size(), 4);
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ(c.key(i), f.key(i));
    EXPECT_EQ(c.varType(i), f.varType(i));
  }
  EXPECT_EQ(c.dim(), f.dim());
  EXPECT_EQ(c.role(), f.role());
  EXPECT_EQ(c.id(), f.id());
  EXPECT_STREQ(c.typeName(), f.typeName());
  const auto* typed = dynamic_cast<const F*>(&c);
  ASSERT_NE(typed, nullptr);
  EXPECT_EQ(typed->measured(), f.measured());
  EXPECT_EQ(typed->information(), f.information());
  EXPECT_EQ(c.whitenedError(v), f.whitenedError(v));
}

TEST(AnchoredSightingFactor, KeysTypesRoleAndClone) {
  std::mt19937 rng(31);
  const Values v2 = values2(randomSE2(rng), randomSE2(rng), randomSE2(rng), randomPoint2(rng));
  const Values v3 = values3(randomSE3(rng), randomSE3(rng), randomSE3(rng), randomPoint3(rng));
  Eigen::Matrix2d info2;
  info2 << 4, 1, 1, 9;
  Mat3 info3;
  info3 << 5, 1, 0, 1, 6, 2, 0, 2, 7;

  AnchoredPosePointFactor2 pp2(kAr, kXr, kAs, kLs, Vec2(1.5, -2), info2);
  EXPECT_EQ(pp2.role(), FactorRole::Landmark);
  EXPECT_EQ(pp2.dim(), 2);
  EXPECT_STREQ(pp2.typeName(), "AnchoredPosePoint2");
  EXPECT_EQ(pp2.measured(), Vec2(1.5, -2));
  EXPECT_EQ(pp2.information(), info2);
  EXPECT_EQ(pp2.varType(0), VarType::SE2);
  EXPECT_EQ(pp2.varType(1), VarType::SE2);
  EXPECT_EQ(pp2.varType(2), VarType::SE2);
  EXPECT_EQ(pp2.varType(3), VarType::Point2);
  EXPECT_EQ(pp2.key(0), kAr);
  EXPECT_EQ(pp2.key(1), kXr);
  EXPECT_EQ(pp2.key(2), kAs);
  EXPECT_EQ(pp2.key(3), kLs);
  pp2.setId(42);
  expectSameFactor(pp2, *pp2.clone(), v2);

  AnchoredPosePointFactor3 pp3(kAr, kXr, kAs, kLs, Vec3(1, 2, 3), info3, FactorRole::LoopClosure);
  EXPECT_EQ(pp3.role(), FactorRole::LoopClosure);
  EXPECT_EQ(pp3.dim(), 3);
  EXPECT_STREQ(pp3.typeName(), "AnchoredPosePoint3");
  EXPECT_EQ(pp3.measured(), Vec3(1, 2, 3));
  EXPECT_EQ(pp3.information(), info3);
  EXPECT_EQ(pp3.varType(0), VarType::SE3);
  EXPECT_EQ(pp3.varType(1), VarType::SE3);
  EXPECT_EQ(pp3.varType(2), VarType::SE3);
  EXPECT_EQ(pp3.varType(3), VarType::Point3);
  pp3.setId(43);
  expectSameFactor(pp3, *pp3.clone(), v3);

  AnchoredBearingRangeFactor2 br(kAr, kXr, kAs, kLs, Vec2(0.3, 4.5), info2);
  EXPECT_EQ(br.role(), FactorRole::Landmark);
  EXPECT_EQ(br.dim(), 2);
  EXPECT_STREQ(br.typeName(), "AnchoredBearingRange2");
  EXPECT_EQ(br.measured(), Vec2(0.3, 4.5));
  EXPECT_EQ(br.information(), info2);
  EXPECT_EQ(br.varType(3), VarType::Point2);
  br.setId(44);
  expectSameFactor(br, *br.clone(), v2);
}

TEST(AnchoredSightingFactor, RejectsInvalidInformation) {
  Eigen::Matrix2d bad;
  bad << 1, 2, 2, 1;  // indefinite
  EXPECT_THROW(AnchoredPosePointFactor2(kAr, kXr, kAs, kLs, Vec2(1, 0), bad),
               std::invalid_argument);
  EXPECT_THROW(AnchoredBearingRangeFactor2(kAr, kXr, kAs, kLs, Vec2(0, 1), bad),
               std::invalid_argument);
  EXPECT_THROW(AnchoredPosePointFactor3(kAr, kXr, kAs, kLs, Vec3(1, 0, 0), -Mat3::Identity()),
               std::invalid_argument);
}

}  // namespace
}  // namespace loopd::server
