// The engine's wire → solver factors: types, roles, measurements and information carried over;
// inter-robot factors through the robots' anchors.
#include "server/wire_factors.h"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>

#include "client/factor_publisher.h"
#include "server/wire.h"
#include "solvers/factors/anchored_between_factor.h"
#include "solvers/factors/between_factor_se2.h"

using namespace loopd;
using namespace loopd::server;
using client::KeyRef;

namespace {

factor_t wireBetween2(int ra, std::int64_t a, int rb, std::int64_t b, double x, double y,
                      double theta, std::int8_t role) {
  factor_t f{};
  f.id = 7;
  f.type = factor_t::BETWEEN_SE2;
  f.role = role;
  f.keys = {client::wireKey(KeyRef::pose(ra, a)), client::wireKey(KeyRef::pose(rb, b))};
  f.num_keys = 2;
  f.measurement = {x, y, theta};
  f.num_measurement = 3;
  f.noise_kind = factor_t::NOISE_INFORMATION;
  f.noise = {100, 0, 0, 200, 0, 1000};  // upper triangle, row-major
  f.num_noise = 6;
  return f;
}

}  // namespace

TEST(WireFactors, BetweenSE2KeepsKeysRoleMeasurementAndInformation) {
  const factor_t w = wireBetween2(0, 3, 0, 9, 1.0, -2.0, 0.5, factor_t::ROLE_LOOP_CLOSURE);
  const std::shared_ptr<Factor> f = buildFactor(w);
  ASSERT_EQ(f->size(), 2);
  EXPECT_EQ(f->key(0), toKey(w.keys[0]));
  EXPECT_EQ(f->key(1), toKey(w.keys[1]));
  EXPECT_EQ(f->role(), FactorRole::LoopClosure);
  const auto& b = dynamic_cast<const BetweenFactorSE2&>(*f);
  EXPECT_DOUBLE_EQ(b.measured().x, 1.0);
  EXPECT_DOUBLE_EQ(b.measured().y, -2.0);
  EXPECT_DOUBLE_EQ(b.measured().theta, 0.5);
  EXPECT_DOUBLE_EQ(b.information()(1, 1), 200.0);
  EXPECT_DOUBLE_EQ(b.information()(2, 2), 1000.0);
  EXPECT_FALSE(isInterRobot(w));
  EXPECT_FALSE(isAnchored(*f));

  // A pose pair at exactly the measurement costs nothing; 0.1 rad off costs 1000·0.1².
  Values v;
  v.insert(f->key(0), SE2(0, 0, 0));
  v.insert(f->key(1), SE2(1.0, -2.0, 0.5));
  EXPECT_NEAR(f->chi2(v), 0.0, 1e-12);
  v.set(v.slot(f->key(1)), SE2(1.0, -2.0, 0.6));
  EXPECT_NEAR(f->chi2(v), 10.0, 1e-9);
}

TEST(WireFactors, OdometryRoleAndPriorSE3FromTheWiresSevenNumbers) {
  EXPECT_EQ(buildFactor(wireBetween2(0, 1, 0, 2, 1, 0, 0, factor_t::ROLE_ODOMETRY))->role(),
            FactorRole::Odometry);
  factor_t p{};
  p.type = factor_t::PRIOR_SE3;
  p.role = factor_t::ROLE_PRIOR;
  p.keys = {client::wireKey(KeyRef::pose(2, 0))};
  p.num_keys = 1;
  const double s = std::sqrt(0.5);
  p.measurement = {1, 2, 3, 0, 0, s, s};  // x y z, then qx qy qz qw: 90° about z
  p.num_measurement = 7;
  p.noise_kind = factor_t::NOISE_INFORMATION;
  p.noise.assign(21, 0.0);
  for (int i = 0, at = 0; i < 6; at += 6 - i, ++i) p.noise[at] = 1.0;  // the diagonal
  p.num_noise = 21;
  const std::shared_ptr<Factor> f = buildFactor(p);
  EXPECT_EQ(f->role(), FactorRole::Prior);
  const SE3 X = se3From(p.measurement);
  double back[7];
  X.toTranslationQuaternion(back);
  for (int i = 0; i < 7; ++i) EXPECT_NEAR(back[i], p.measurement[i], 1e-12) << i;
  Values v;
  v.insert(f->key(0), X);
  EXPECT_NEAR(f->chi2(v), 0.0, 1e-12);
  EXPECT_NEAR(se3Of(v, f->key(0)).t.z(), 3.0, 1e-12);
}

TEST(WireFactors, UnknownTypeThrows) {
  factor_t w = wireBetween2(0, 1, 0, 2, 1, 0, 0, factor_t::ROLE_ODOMETRY);
  w.type = 42;
  EXPECT_THROW(buildFactor(w), std::invalid_argument);
}

TEST(WireFactors, InterRobotBetweenGoesThroughBothAnchors) {
  const factor_t w = wireBetween2(1, 4, 2, 6, 0.5, 0.25, -0.3, factor_t::ROLE_LOOP_CLOSURE);
  EXPECT_TRUE(isInterRobot(w));
  const std::shared_ptr<Factor> built = buildFactor(w);
  const std::shared_ptr<Factor> a = anchoredFactor(*built);
  ASSERT_EQ(a->size(), 4);
  EXPECT_TRUE(isAnchored(*a));
  EXPECT_EQ(a->role(), FactorRole::LoopClosure);
  EXPECT_EQ(a->key(0), anchorKey(1));
  EXPECT_EQ(a->key(1), toKey(w.keys[0]));
  EXPECT_EQ(a->key(2), anchorKey(2));
  EXPECT_EQ(a->key(3), toKey(w.keys[1]));
  EXPECT_NE(anchorKey(1), anchorKey(2));

  // Robot 1's anchor at the identity, robot 2's frame moved by A and its pose by A⁻¹ (the same
  // common-frame poses): the plain between factor's χ².
  const SE2 xr(1, 2, 0.3), xs(1.4, 2.5, 0.1), A(3, -1, 0.7);
  Values plain, anchored;
  plain.insert(built->key(0), xr);
  plain.insert(built->key(1), xs);
  anchored.insert(anchorKey(1), SE2());
  anchored.insert(a->key(1), xr);
  anchored.insert(anchorKey(2), A);
  anchored.insert(a->key(3), A.inverse() * xs);
  EXPECT_GT(built->chi2(plain), 0.0);
  EXPECT_NEAR(a->chi2(anchored), built->chi2(plain), 1e-9);
  EXPECT_NEAR(se2Of(anchored, anchorKey(2)).theta, 0.7, 1e-15);
}

// A pose of robot 1 sighting robot 2's landmark: the same measurement through both anchors,
// id and robust request kept, and an inter-robot edge that names the landmark.
TEST(WireFactors, CrossRobotSightingGoesThroughBothAnchors) {
  for (const bool bearingRange : {false, true}) {
    const factor_t w =
        bearingRange ? client::bearingRangeFactor(KeyRef::pose(1, 4), KeyRef::point(2, 7), 0.3, 5.0,
                                                  Eigen::Matrix2d::Identity() * 50)
                     : client::landmarkFactor(KeyRef::pose(1, 4), KeyRef::point(2, 7),
                                              Eigen::Vector2d(1, 2), Eigen::Matrix2d::Identity());
    EXPECT_TRUE(isCrossRobotSighting(w));
    EXPECT_FALSE(isInterRobot(w));
    const std::shared_ptr<Factor> built = buildFactor(w);
    built->setId(42);
    built->setRobustRequest({"dcs", 2.0});
    const std::shared_ptr<Factor> a = anchoredFactor(*built);
    ASSERT_EQ(a->size(), 4);
    EXPECT_STREQ(a->typeName(), bearingRange ? "AnchoredBearingRange2" : "AnchoredPosePoint2");
    EXPECT_EQ(a->role(), FactorRole::Landmark);
    EXPECT_EQ(a->id(), 42u);
    EXPECT_EQ(a->robustRequest().variant, "dcs");
    EXPECT_EQ(a->key(0), anchorKey(1));
    EXPECT_EQ(a->key(1), toKey(w.keys[0]));
    EXPECT_EQ(a->key(2), anchorKey(2));
    EXPECT_EQ(a->key(3), toKey(w.keys[1]));
    // With both anchors at identity it is the plain sighting.
    Values v;
    v.insert(anchorKey(1), SE2());
    v.insert(anchorKey(2), SE2());
    v.insert(toKey(w.keys[0]), SE2(0.5, -1, 0.4));
    v.insertPoint2(toKey(w.keys[1]), Vec2(3, 1));
    EXPECT_NEAR(a->chi2(v), built->chi2(v), 1e-12);
    EXPECT_GT(a->chi2(v), 0.0);
    const InterEdge e = interEdgeOf(*a);
    EXPECT_EQ(e.r, 1u);
    EXPECT_EQ(e.s, 2u);
    EXPECT_EQ(e.landmark, toKey(w.keys[1]));
    EXPECT_EQ(e.needed, 2);
  }
  const factor_t same = client::landmarkFactor(KeyRef::pose(1, 4), KeyRef::point(1, 7),
                                               Eigen::Vector2d(1, 2), Eigen::Matrix2d::Identity());
  EXPECT_FALSE(isCrossRobotSighting(same));
  EXPECT_EQ(interEdgeOf(*anchoredFactor(*buildFactor(wireBetween2(1, 4, 2, 6, 0.5, 0.25, -0.3,
                                                                  factor_t::ROLE_LOOP_CLOSURE))))
                .landmark,
            0u);
}
