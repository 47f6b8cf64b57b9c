// Inter-robot between factors through the robots' anchors: Jacobians, and the plain between
// factor of the common-frame poses they evaluate.
#include "solvers/factors/anchored_between_factor.h"

#include <gtest/gtest.h>

#include <random>

#include "solvers/geometry/se3.h"
#include "tests/solvers/factors/jacobian_check.h"

namespace loopd {
namespace {

TEST(AnchoredBetweenFactor, SE2JacobiansMatchNumerical) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-2, 2);
  for (int trial = 0; trial < 20; ++trial) {
    Values v;
    const Key ar = makeKey(0, KeyKind::Anchor, 0), xr = poseKey(5, 0),
              as = makeKey(1, KeyKind::Anchor, 0), xs = poseKey(9, 1);
    v.insert(ar, SE2(u(rng), u(rng), u(rng)));
    v.insert(xr, SE2(u(rng), u(rng), u(rng)));
    v.insert(as, SE2(u(rng), u(rng), u(rng)));
    v.insert(xs, SE2(u(rng), u(rng), u(rng)));
    Eigen::Matrix3d info;
    info << 40, 3, 1, 3, 20, 2, 1, 2, 90;
    AnchoredBetweenFactorSE2 f(ar, xr, as, xs, SE2(u(rng), u(rng), u(rng)), info);
    test::checkJacobians(f, v, "", 1e-6, 1e-5, true);
  }
}

TEST(AnchoredBetweenFactor, SE3JacobiansMatchNumerical) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  auto rnd = [&] {
    Vec6 xi;
    for (int i = 0; i < 6; ++i) xi[i] = u(rng);
    return expSE3(xi);
  };
  for (int trial = 0; trial < 20; ++trial) {
    Values v;
    const Key ar = makeKey(0, KeyKind::Anchor, 0), xr = poseKey(5, 0),
              as = makeKey(1, KeyKind::Anchor, 0), xs = poseKey(9, 1);
    v.insert(ar, rnd());
    v.insert(xr, rnd());
    v.insert(as, rnd());
    v.insert(xs, rnd());
    Mat6 info = Mat6::Identity() * 10;
    info(0, 1) = info(1, 0) = 2;
    info(3, 5) = info(5, 3) = 1;
    AnchoredBetweenFactorSE3 f(ar, xr, as, xs, rnd(), info);
    test::checkJacobians(f, v, "", 1e-6, 1e-5, true);
  }
}

TEST(AnchoredBetweenFactor, EqualsPlainBetweenOfCommonFramePoses) {
  const SE2 Ar(1, 2, 0.3), xr(0.5, -1, 0.2), As(-3, 1, -1), xs(2, 2, 0.7), Z(0.4, 0.1, -0.2);
  Eigen::Matrix3d info = Eigen::Matrix3d::Identity() * 5;
  Values v;
  const Key ar = makeKey(0, KeyKind::Anchor, 0), pr = poseKey(1, 0),
            as = makeKey(1, KeyKind::Anchor, 0), ps = poseKey(1, 1);
  v.insert(ar, Ar);
  v.insert(pr, xr);
  v.insert(as, As);
  v.insert(ps, xs);
  AnchoredBetweenFactorSE2 f(ar, pr, as, ps, Z, info);
  Values w;
  w.insert(poseKey(0), Ar * xr);
  w.insert(poseKey(1), As * xs);
  BetweenFactorSE2 g(poseKey(0), poseKey(1), Z, info);
  EXPECT_NEAR(f.chi2(v), g.chi2(w), 1e-9);
}

}  // namespace
}  // namespace loopd
