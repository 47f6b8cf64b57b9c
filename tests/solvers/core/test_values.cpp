// Keys (packing, ordering, names) and Values (slots, insert, set/get, retract).
#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

#include "solvers/core/key.h"
#include "solvers/core/values.h"

namespace loopd {
namespace {

const KeyKind kKinds[] = {KeyKind::Pose, KeyKind::Landmark, KeyKind::Anchor, KeyKind::Switch};

// ----------------------------------------------------------------------------------- keys

TEST(Key, PackUnpackRoundTrip) {
  const std::uint32_t robots[] = {0u, 1u, 2u, 255u, 256u, 0x1234u, kMaxRobotId};
  const std::uint64_t indices[] = {0u, 1u, 42u, 0xFFFFFFFFull, 0x100000000ull, kMaxKeyIndex};
  for (std::uint32_t r : robots)
    for (KeyKind kind : kKinds)
      for (std::uint64_t i : indices) {
        const Key k = makeKey(r, kind, i);
        EXPECT_EQ(keyRobot(k), r);
        EXPECT_EQ(keyKind(k), kind);
        EXPECT_EQ(keyIndex(k), i);
      }
  EXPECT_EQ(poseKey(7, 3), makeKey(3, KeyKind::Pose, 7));
  EXPECT_EQ(landmarkKey(7, 3), makeKey(3, KeyKind::Landmark, 7));
  EXPECT_EQ(poseKey(7), makeKey(0, KeyKind::Pose, 7));
  EXPECT_NE(poseKey(7), landmarkKey(7));
  EXPECT_NE(poseKey(7, 0), poseKey(7, 1));
  // Distinct fields never collide.
  std::vector<Key> all;
  for (std::uint32_t r : robots)
    for (KeyKind kind : kKinds)
      for (std::uint64_t i : indices) all.push_back(makeKey(r, kind, i));
  std::sort(all.begin(), all.end());
  EXPECT_EQ(std::unique(all.begin(), all.end()), all.end());
  // Compile-time usable.
  static_assert(keyIndex(poseKey(5, 2)) == 5, "constexpr");
  static_assert(keyRobot(poseKey(5, 2)) == 2, "constexpr");
}

TEST(Key, OrderingIsRobotThenKindThenIndex) {
  // Robot dominates kind and index.
  EXPECT_LT(makeKey(0, KeyKind::Switch, kMaxKeyIndex), makeKey(1, KeyKind::Pose, 0));
  // Kind dominates index.
  EXPECT_LT(makeKey(3, KeyKind::Pose, kMaxKeyIndex), makeKey(3, KeyKind::Landmark, 0));
  EXPECT_LT(makeKey(3, KeyKind::Landmark, kMaxKeyIndex), makeKey(3, KeyKind::Anchor, 0));
  EXPECT_LT(makeKey(3, KeyKind::Anchor, kMaxKeyIndex), makeKey(3, KeyKind::Switch, 0));
  // Index orders within a kind.
  EXPECT_LT(poseKey(9, 2), poseKey(10, 2));
  EXPECT_LT(makeKey(kMaxRobotId - 1, KeyKind::Switch, kMaxKeyIndex),
            makeKey(kMaxRobotId, KeyKind::Pose, 0));

  std::mt19937 rng(21);
  std::uniform_int_distribution<std::uint32_t> robot(0, 5);
  std::uniform_int_distribution<int> kind(0, 3);
  std::uniform_int_distribution<std::uint64_t> index(0, 1000);
  std::vector<Key> keys;
  for (int i = 0; i < 500; ++i)
    keys.push_back(makeKey(robot(rng), static_cast<KeyKind>(kind(rng)), index(rng)));
  std::sort(keys.begin(), keys.end());
  for (size_t i = 1; i < keys.size(); ++i) {
    const Key a = keys[i - 1], b = keys[i];
    const auto ta = std::make_tuple(keyRobot(a), static_cast<int>(keyKind(a)), keyIndex(a));
    const auto tb = std::make_tuple(keyRobot(b), static_cast<int>(keyKind(b)), keyIndex(b));
    EXPECT_LE(ta, tb);
  }
}

TEST(Key, ToString) {
  EXPECT_EQ(keyToString(poseKey(12)), "r0:x12");
  EXPECT_EQ(keyToString(landmarkKey(3, 1)), "r1:l3");
  EXPECT_EQ(keyToString(makeKey(0, KeyKind::Anchor, 0)), "r0:a0");
  EXPECT_EQ(keyToString(makeKey(0, KeyKind::Switch, 7)), "r0:s7");
  EXPECT_EQ(keyToString(makeKey(kMaxRobotId, KeyKind::Pose, kMaxKeyIndex)),
            "r65535:x1099511627775");
  // An unknown kind (corrupt key) still prints, with '?'.
  const Key bad = (Key{9} << kKeyIndexBits) | 4u;
  EXPECT_EQ(keyToString(bad), "r0:?4");
}

// --------------------------------------------------------------------------------- values

bool isRotation(const Mat3& R, double tol) {
  return (R.transpose() * R - Mat3::Identity()).norm() < tol &&
         std::abs(R.determinant() - 1.0) < tol;
}

TEST(Values, VarDimsAndNames) {
  EXPECT_EQ(varDim(VarType::SE2), 3);
  EXPECT_EQ(varDim(VarType::SE3), 6);
  EXPECT_EQ(varDim(VarType::Point2), 2);
  EXPECT_EQ(varDim(VarType::Point3), 3);
  EXPECT_EQ(varDim(VarType::Scalar), 1);
  EXPECT_STREQ(varTypeName(VarType::SE3), "SE3");
  EXPECT_STREQ(varTypeName(VarType::Point2), "Point2");
  EXPECT_LE(varDim(VarType::SE3), kMaxVarDim);
}

TEST(Values, InsertSlotAndGetEveryType) {
  Values v;
  EXPECT_TRUE(v.empty());
  const SE2 a(1.0, -2.0, 0.3);
  const SE3 b(expSO3(Vec3(0.1, -0.2, 0.3)), Vec3(4.0, 5.0, 6.0));
  const Vec2 p2(7.0, 8.0);
  const Vec3 p3(9.0, 10.0, 11.0);
  EXPECT_EQ(v.insert(poseKey(0), a), 0);
  EXPECT_EQ(v.insert(poseKey(1, 1), b), 1);
  EXPECT_EQ(v.insertPoint2(landmarkKey(0), p2), 2);
  EXPECT_EQ(v.insertPoint3(landmarkKey(1), p3), 3);
  EXPECT_EQ(v.insertScalar(makeKey(0, KeyKind::Switch, 0), 0.75), 4);
  ASSERT_EQ(v.size(), 5);
  EXPECT_FALSE(v.empty());

  EXPECT_EQ(v.slot(poseKey(0)), 0);
  EXPECT_EQ(v.slot(poseKey(1, 1)), 1);
  EXPECT_EQ(v.slot(landmarkKey(1)), 3);
  EXPECT_EQ(v.slot(poseKey(1)), -1);  // robot 0's x1 was never inserted
  EXPECT_TRUE(v.contains(landmarkKey(0)));
  EXPECT_FALSE(v.contains(landmarkKey(2)));
  EXPECT_EQ(v.key(2), landmarkKey(0));
  EXPECT_EQ(v.keys(), (std::vector<Key>{poseKey(0), poseKey(1, 1), landmarkKey(0), landmarkKey(1),
                                        makeKey(0, KeyKind::Switch, 0)}));
  EXPECT_EQ(v.type(0), VarType::SE2);
  EXPECT_EQ(v.type(1), VarType::SE3);
  EXPECT_EQ(v.type(2), VarType::Point2);
  EXPECT_EQ(v.type(3), VarType::Point3);
  EXPECT_EQ(v.type(4), VarType::Scalar);

  EXPECT_EQ(v.se2(0).x, a.x);
  EXPECT_EQ(v.se2(0).y, a.y);
  EXPECT_EQ(v.se2(0).theta, a.theta);
  EXPECT_EQ(v.se3(1).R, b.R);
  EXPECT_EQ(v.se3(1).t, b.t);
  EXPECT_EQ(v.point2(2), p2);
  EXPECT_EQ(v.point3(3), p3);
  EXPECT_EQ(v.scalar(4), 0.75);

  // Storage layout: SE3 is R column-major then t.
  const double* d = v.data(1);
  EXPECT_EQ(d[0], b.R(0, 0));
  EXPECT_EQ(d[1], b.R(1, 0));
  EXPECT_EQ(d[3], b.R(0, 1));
  EXPECT_EQ(d[9], b.t.x());
  EXPECT_EQ(d[11], b.t.z());
  EXPECT_EQ(v.data(2) - v.data(1), kValueStride);
}

TEST(Values, DuplicateInsertThrowsAndLeavesValuesUnchanged) {
  Values v;
  v.insert(poseKey(0), SE2(1.0, 2.0, 0.5));
  v.insertPoint3(landmarkKey(0), Vec3(1.0, 2.0, 3.0));
  EXPECT_THROW(v.insert(poseKey(0), SE2()), std::invalid_argument);
  EXPECT_THROW(v.insert(poseKey(0), SE3()), std::invalid_argument);
  EXPECT_THROW(v.insertPoint2(poseKey(0), Vec2::Zero()), std::invalid_argument);
  EXPECT_THROW(v.insertPoint3(landmarkKey(0), Vec3::Zero()), std::invalid_argument);
  EXPECT_THROW(v.insertScalar(landmarkKey(0), 0.0), std::invalid_argument);
  EXPECT_THROW(v.insertFrom(v, 0), std::invalid_argument);
  EXPECT_EQ(v.size(), 2);
  EXPECT_EQ(v.keys().size(), 2u);
  EXPECT_EQ(v.type(0), VarType::SE2);
  EXPECT_EQ(v.se2(0).x, 1.0);
  EXPECT_EQ(v.point3(1), Vec3(1.0, 2.0, 3.0));
  // Still usable after the failed inserts.
  EXPECT_EQ(v.insertPoint2(landmarkKey(1), Vec2(5.0, 6.0)), 2);
  EXPECT_EQ(v.point2(2), Vec2(5.0, 6.0));
  try {
    v.insert(poseKey(0), SE2());
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("r0:x0"), std::string::npos) << e.what();
  }
}

TEST(Values, AllFiniteFindsNanAndInfinity) {
  Values v;
  EXPECT_TRUE(v.allFinite());
  v.insert(poseKey(0), SE2(1.0, 2.0, 0.3));
  v.insertPoint3(landmarkKey(1), Vec3(1, 2, 3));
  EXPECT_TRUE(v.allFinite());
  Values nan = v, inf = v;
  nan.data(0)[1] = std::numeric_limits<double>::quiet_NaN();
  inf.data(1)[2] = -std::numeric_limits<double>::infinity();
  EXPECT_FALSE(nan.allFinite());
  EXPECT_FALSE(inf.allFinite());
  EXPECT_TRUE(v.allWithin(3.0));
  EXPECT_FALSE(v.allWithin(2.5));  // the landmark's z
  EXPECT_FALSE(nan.allWithin(1e300));
  EXPECT_FALSE(inf.allWithin(1e300));
  Values huge = v;
  huge.data(0)[0] = -1e13;  // finite, but beyond the bound
  EXPECT_TRUE(huge.allFinite());
  EXPECT_FALSE(huge.allWithin(1e12));
  EXPECT_EQ(v.largestMagnitude(), 3.0);  // the landmark's z
  EXPECT_EQ(huge.largestMagnitude(), 1e13);
  EXPECT_EQ(nan.largestMagnitude(), 3.0);  // NaN skipped
  EXPECT_EQ(inf.largestMagnitude(), std::numeric_limits<double>::infinity());
  nan.data(1)[0] = -std::numeric_limits<double>::quiet_NaN();  // sign bit set too
  EXPECT_EQ(nan.largestMagnitude(), 3.0);
  EXPECT_EQ(Values().largestMagnitude(), 0.0);
}

TEST(Values, SetInsertFromAssignFrom) {
  Values v;
  v.insert(poseKey(0), SE2(1.0, 2.0, 0.5));
  v.insert(poseKey(1), SE3());
  v.insertPoint2(landmarkKey(0), Vec2(1.0, 1.0));
  v.insertPoint3(landmarkKey(1), Vec3(1.0, 1.0, 1.0));
  v.insertScalar(makeKey(0, KeyKind::Switch, 0), 1.0);
  v.set(0, SE2(-1.0, -2.0, -0.5));
  const SE3 x(expSO3(Vec3(0.4, 0.5, -0.6)), Vec3(1.0, 2.0, 3.0));
  v.set(1, x);
  v.setPoint2(2, Vec2(3.0, 4.0));
  v.setPoint3(3, Vec3(5.0, 6.0, 7.0));
  v.setScalar(4, 0.25);
  EXPECT_EQ(v.se2(0).theta, -0.5);
  EXPECT_EQ(v.se3(1).R, x.R);
  EXPECT_EQ(v.point2(2), Vec2(3.0, 4.0));
  EXPECT_EQ(v.point3(3), Vec3(5.0, 6.0, 7.0));
  EXPECT_EQ(v.scalar(4), 0.25);

  Values w;
  w.insertFrom(v, 3);
  w.insertFrom(v, 1);
  ASSERT_EQ(w.size(), 2);
  EXPECT_EQ(w.key(0), landmarkKey(1));
  EXPECT_EQ(w.type(0), VarType::Point3);
  EXPECT_EQ(w.point3(0), v.point3(3));
  EXPECT_EQ(w.type(1), VarType::SE3);
  EXPECT_EQ(w.se3(1).R, x.R);
  EXPECT_EQ(w.se3(1).t, x.t);

  Values u = v;
  u.setScalar(4, 9.0);
  u.set(0, SE2());
  v.assignFrom(u);
  EXPECT_EQ(v.scalar(4), 9.0);
  EXPECT_EQ(v.se2(0).x, 0.0);
}

TEST(Values, RetractEveryType) {
  std::mt19937 rng(22);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    Values v;
    const SE2 a(3.0 * u(rng), 3.0 * u(rng), 3.0 * u(rng));
    const SE3 b(expSO3(3.0 * Vec3(u(rng), u(rng), u(rng)).normalized() * std::abs(u(rng))),
                Vec3(u(rng), u(rng), u(rng)));
    const Vec2 p2(u(rng), u(rng));
    const Vec3 p3(u(rng), u(rng), u(rng));
    const double s = u(rng);
    v.insert(poseKey(0), a);
    v.insert(poseKey(1), b);
    v.insertPoint2(landmarkKey(0), p2);
    v.insertPoint3(landmarkKey(1), p3);
    v.insertScalar(makeKey(0, KeyKind::Switch, 0), s);

    const Eigen::Vector3d d2(u(rng), u(rng), u(rng));
    Vec6 d3;
    for (int i = 0; i < 6; ++i) d3[i] = u(rng);
    const Vec2 dp2(u(rng), u(rng));
    const Vec3 dp3(u(rng), u(rng), u(rng));
    const double ds = u(rng);

    v.retract(0, d2.data());
    const SE2 ea = a * SE2(d2.x(), d2.y(), d2.z());
    EXPECT_NEAR(v.se2(0).x, ea.x, 1e-12);
    EXPECT_NEAR(v.se2(0).y, ea.y, 1e-12);
    EXPECT_NEAR(wrapAngle(v.se2(0).theta - ea.theta), 0.0, 1e-12);

    v.retract(1, d3.data());
    const SE3 X = v.se3(1);
    EXPECT_TRUE(isRotation(X.R, 1e-14));
    EXPECT_LT((X.R - b.R * expSO3(d3.tail<3>())).norm(), 1e-12);
    EXPECT_LT((X.t - (b.t + b.R * d3.head<3>())).norm(), 1e-12);

    v.retract(2, dp2.data());
    EXPECT_LT((v.point2(2) - (p2 + dp2)).norm(), 1e-15);
    v.retract(3, dp3.data());
    EXPECT_LT((v.point3(3) - (p3 + dp3)).norm(), 1e-15);
    v.retract(4, &ds);
    EXPECT_DOUBLE_EQ(v.scalar(4), s + ds);
  }
}

TEST(Values, Se3RetractKeepsRotationOrthonormalOverManySteps) {
  std::mt19937 rng(23);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  Values v;
  // Start from a slightly non-orthonormal rotation: retract re-orthonormalises it.
  Mat3 R0 = expSO3(Vec3(0.3, -1.2, 2.0));
  R0(0, 1) += 1e-7;
  v.insert(poseKey(0), SE3(R0, Vec3(1.0, 2.0, 3.0)));
  const Vec6 zero = Vec6::Zero();
  v.retract(0, zero.data());
  ASSERT_TRUE(isRotation(v.se3(0).R, 1e-14));
  EXPECT_LT((v.se3(0).R - R0).norm(), 1e-6);
  Mat3 Rref = v.se3(0).R;
  for (int i = 0; i < 10000; ++i) {
    Vec6 d;
    for (int k = 0; k < 6; ++k) d[k] = u(rng);
    v.retract(0, d.data());
    Rref = Rref * expSO3(d.tail<3>());
    const Mat3 R = v.se3(0).R;
    ASSERT_TRUE(isRotation(R, 1e-13)) << "step " << i << "\n" << R;
  }
  EXPECT_LT((v.se3(0).R - projectToSO3(Rref)).norm(), 1e-9);
}

TEST(Values, RetractAllUsesOffsetsAndSkipsNegative) {
  Values v;
  v.insert(poseKey(0), SE2(0.0, 0.0, 0.0));
  v.insertPoint2(landmarkKey(0), Vec2(1.0, 1.0));
  v.insert(poseKey(1), SE2(1.0, 0.0, 0.5));
  v.insertScalar(makeKey(0, KeyKind::Switch, 0), 1.0);
  // Slot 0 fixed; others packed in a different order than the slots.
  const std::vector<int> offsets = {-1, 4, 0, 3};
  const std::vector<double> delta = {0.1, 0.2, 0.3, -0.5, 10.0, 20.0};
  v.retractAll(offsets, delta.data());
  EXPECT_EQ(v.se2(0).x, 0.0);
  EXPECT_EQ(v.se2(0).theta, 0.0);
  EXPECT_EQ(v.point2(1), Vec2(11.0, 21.0));
  const SE2 e = SE2(1.0, 0.0, 0.5) * SE2(0.1, 0.2, 0.3);
  EXPECT_NEAR(v.se2(2).x, e.x, 1e-15);
  EXPECT_NEAR(v.se2(2).y, e.y, 1e-15);
  EXPECT_NEAR(v.se2(2).theta, 0.8, 1e-15);
  EXPECT_DOUBLE_EQ(v.scalar(3), 0.5);
}

TEST(Values, Se2RetractWrapsAngle) {
  Values v;
  v.insert(poseKey(0), SE2(0.0, 0.0, M_PI - 0.1));
  const double d[3] = {0.0, 0.0, 0.3};
  v.retract(0, d);
  EXPECT_NEAR(v.se2(0).theta, -M_PI + 0.2, 1e-12);
}

}  // namespace
}  // namespace loopd
