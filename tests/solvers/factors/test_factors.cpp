// Every factor type: analytic whitened Jacobians against central differences taken through
// Values::retract, zero residual at the measurement, chi2 against an independently built
// error, information-matrix validation, clone().
#include <gtest/gtest-spi.h>
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/factors/factor.h"
#include "solvers/factors/landmark_factors.h"
#include "solvers/factors/prior_factors.h"
#include "tests/solvers/factors/jacobian_check.h"
#include "tests/solvers/geometry/matrix_forms.h"

namespace loopd {
namespace {

using test::checkJacobians;
using test::homogeneous;
using test::randomInformation;
using test::randomUnit;

using Mat4 = Eigen::Matrix4d;
using Eigen::MatrixXd;
using Eigen::VectorXd;
constexpr double kPi = M_PI;

// ------------------------------------------------------------------------------- helpers

SE2 randomSE2(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-5.0, 5.0), a(-kPi, kPi);
  return {u(rng), u(rng), a(rng)};
}

SE3 randomSE3(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-5.0, 5.0), a(0.0, 3.1);
  return {expSO3(randomUnit(rng) * a(rng)), Vec3(u(rng), u(rng), u(rng))};
}

SE3 rotationOnly(const Vec3& w) { return {expSO3(w), Vec3::Zero()}; }

// Log of SE(3), built independently of solvers/geometry: angle-axis from Eigen, and
// ρ = V⁻¹ t with V = I + (1−cosθ)/θ² [φ]× + (θ−sinθ)/θ³ [φ]×².
Vec6 referenceLogSE3(const Mat4& T) {
  const Eigen::AngleAxisd aa(Mat3(T.topLeftCorner<3, 3>()));
  const Vec3 phi = aa.angle() * aa.axis();
  const double th = phi.norm();
  Mat3 P;
  P << 0.0, -phi.z(), phi.y(), phi.z(), 0.0, -phi.x(), -phi.y(), phi.x(), 0.0;
  Mat3 V = Mat3::Identity();
  if (th > 1e-8)
    V += (1.0 - std::cos(th)) / (th * th) * P + (th - std::sin(th)) / (th * th * th) * P * P;
  else
    V += 0.5 * P + P * P / 6.0;
  Vec6 e;
  e.head<3>() = V.inverse() * T.topRightCorner<3, 1>();
  e.tail<3>() = phi;
  return e;
}

// One factor with a full set of values for its keys.
struct Case {
  std::string name;
  std::shared_ptr<Factor> factor;
  Values values;
};

// ------------------------------------------------------------------ cases for every type

std::vector<Case> betweenSE2Cases() {
  std::mt19937 rng(101);
  std::vector<Case> cases;
  auto add = [&](const std::string& name, const SE2& xi, const SE2& xj, const SE2& z) {
    Case c{name,
           std::make_shared<BetweenFactorSE2>(poseKey(1), poseKey(2), z, randomInformation<3>(rng)),
           {}};
    c.values.insert(poseKey(1), xi);
    c.values.insert(poseKey(2), xj);
    cases.push_back(std::move(c));
  };
  for (int i = 0; i < 8; ++i)
    add("random" + std::to_string(i), randomSE2(rng), randomSE2(rng), randomSE2(rng));
  add("coincident poses, identity measurement", SE2(1.0, 2.0, 0.3), SE2(1.0, 2.0, 0.3), SE2());
  add("at measurement", SE2(1.0, 2.0, 3.0), SE2(1.0, 2.0, 3.0) * SE2(0.5, -0.2, 0.4),
      SE2(0.5, -0.2, 0.4));
  add("angles straddling ±π", SE2(0.0, 0.0, kPi - 1e-3), SE2(1.0, 0.0, -kPi + 1e-3),
      SE2(1.0, 0.0, 0.002));
  add("angle residual near π", SE2(0.0, 0.0, 0.5), SE2(1.0, 0.0, 0.5 + kPi - 0.01), SE2());
  add("angle residual near −π", SE2(0.0, 0.0, 0.5), SE2(1.0, 0.0, 0.5 - kPi + 0.01), SE2());
  add("large translation", SE2(1e3, -2e3, 1.0), SE2(-1e3, 2e3, -2.0), SE2(5.0, 5.0, 0.1));
  return cases;
}

std::vector<Case> betweenSE3Cases() {
  std::mt19937 rng(102);
  std::vector<Case> cases;
  auto add = [&](const std::string& name, const SE3& xi, const SE3& xj, const SE3& z) {
    Case c{name,
           std::make_shared<BetweenFactorSE3>(poseKey(1), poseKey(2), z, randomInformation<6>(rng)),
           {}};
    c.values.insert(poseKey(1), xi);
    c.values.insert(poseKey(2), xj);
    cases.push_back(std::move(c));
  };
  for (int i = 0; i < 8; ++i)
    add("random" + std::to_string(i), randomSE3(rng), randomSE3(rng), randomSE3(rng));
  const SE3 X = randomSE3(rng), Z = randomSE3(rng);
  add("coincident poses, identity measurement", X, X, SE3());
  add("at measurement", X, X * Z, Z);
  add("residual rotation 1e-9", X, X * Z * rotationOnly(randomUnit(rng) * 1e-9), Z);
  add("residual rotation 1e-4", X, X * Z * SE3(expSO3(randomUnit(rng) * 1e-4), Vec3(1, 2, 3)), Z);
  add("residual rotation 3.0", X, X * Z * SE3(expSO3(randomUnit(rng) * 3.0), Vec3(0.5, 0, 1)), Z);
  add("residual rotation 3.1", X, X * Z * rotationOnly(randomUnit(rng) * 3.1), Z);
  add("poses rotated by ~π", rotationOnly(Vec3(kPi - 1e-6, 0, 0)),
      SE3(expSO3(Vec3(0, kPi - 1e-6, 0)), Vec3(1, 1, 1)), randomSE3(rng));
  return cases;
}

std::vector<Case> priorCases() {
  std::mt19937 rng(103);
  std::vector<Case> cases;
  auto addSE2 = [&](const std::string& name, const SE2& x, const SE2& z) {
    Case c{"PriorSE2 " + name,
           std::make_shared<PriorFactorSE2>(poseKey(4), z, randomInformation<3>(rng)),
           {}};
    c.values.insert(poseKey(4), x);
    cases.push_back(std::move(c));
  };
  auto addSE3 = [&](const std::string& name, const SE3& x, const SE3& z) {
    Case c{"PriorSE3 " + name,
           std::make_shared<PriorFactorSE3>(poseKey(4), z, randomInformation<6>(rng)),
           {}};
    c.values.insert(poseKey(4), x);
    cases.push_back(std::move(c));
  };
  for (int i = 0; i < 6; ++i) addSE2("random" + std::to_string(i), randomSE2(rng), randomSE2(rng));
  addSE2("at prior", SE2(1.0, 2.0, -3.0), SE2(1.0, 2.0, -3.0));
  addSE2("angle across ±π", SE2(1.0, 2.0, -kPi + 1e-3), SE2(0.0, 0.0, kPi - 1e-3));
  addSE2("angle residual near π", SE2(1.0, 2.0, kPi - 0.01), SE2(0.0, 0.0, 0.0));
  for (int i = 0; i < 6; ++i) addSE3("random" + std::to_string(i), randomSE3(rng), randomSE3(rng));
  const SE3 Z = randomSE3(rng);
  addSE3("at prior", Z, Z);
  addSE3("residual rotation 1e-8", Z * rotationOnly(randomUnit(rng) * 1e-8), Z);
  addSE3("residual rotation 3.05", Z * SE3(expSO3(randomUnit(rng) * 3.05), Vec3(1, -1, 2)), Z);
  for (int i = 0; i < 4; ++i) {
    std::uniform_real_distribution<double> u(-10.0, 10.0);
    Case c2{"PriorPoint2 random" + std::to_string(i),
            std::make_shared<PriorFactorPoint2>(landmarkKey(1), Vec2(u(rng), u(rng)),
                                                randomInformation<2>(rng)),
            {}};
    c2.values.insertPoint2(landmarkKey(1), Vec2(u(rng), u(rng)));
    cases.push_back(std::move(c2));
    Case c3{"PriorPoint3 random" + std::to_string(i),
            std::make_shared<PriorFactorPoint3>(landmarkKey(1), Vec3(u(rng), u(rng), u(rng)),
                                                randomInformation<3>(rng)),
            {}};
    c3.values.insertPoint3(landmarkKey(1), Vec3(u(rng), u(rng), u(rng)));
    cases.push_back(std::move(c3));
  }
  return cases;
}

std::vector<Case> landmarkCases() {
  std::mt19937 rng(104);
  std::uniform_real_distribution<double> u(-10.0, 10.0);
  std::vector<Case> cases;
  auto add2 = [&](const std::string& name, std::shared_ptr<Factor> f, const SE2& x, const Vec2& p) {
    Case c{name, std::move(f), {}};
    c.values.insert(poseKey(3), x);
    c.values.insertPoint2(landmarkKey(5), p);
    cases.push_back(std::move(c));
  };
  auto pp2 = [&](const Vec2& z) {
    return std::make_shared<PosePointFactor2>(poseKey(3), landmarkKey(5), z,
                                              randomInformation<2>(rng));
  };
  auto br2 = [&](double b, double r) {
    return std::make_shared<BearingRangeFactor2>(poseKey(3), landmarkKey(5), Vec2(b, r),
                                                 randomInformation<2>(rng));
  };
  for (int i = 0; i < 6; ++i) {
    add2("PosePoint2 random" + std::to_string(i), pp2(Vec2(u(rng), u(rng))), randomSE2(rng),
         Vec2(u(rng), u(rng)));
    add2("BearingRange2 random" + std::to_string(i), br2(0.3 * u(rng), std::abs(u(rng))),
         randomSE2(rng), Vec2(u(rng), u(rng)));
  }
  const SE2 X(1.0, -2.0, 2.5);
  add2("PosePoint2 landmark on the pose", pp2(Vec2(1.0, 0.0)), X, X.t());
  add2("PosePoint2 landmark 1e-6 from the pose", pp2(Vec2(1.0, 0.0)), X,
       X.transform(Vec2(1e-6, 0)));
  add2("BearingRange2 landmark straight behind, bearing π", br2(kPi, 2.0), X,
       X.transform(Vec2(-2.0, 0.0)));
  add2("BearingRange2 landmark straight behind, bearing −π+1e-3", br2(-kPi + 1e-3, 2.0), X,
       X.transform(Vec2(-2.0, 1e-9)));
  add2("BearingRange2 landmark on the x axis", br2(0.0, 3.0), X, X.transform(Vec2(3.0, 0.0)));
  add2("BearingRange2 landmark close (5 cm)", br2(0.5, 0.05), X, X.transform(Vec2(0.03, -0.04)));
  add2("BearingRange2 at measurement", br2(-2.0, 4.0), X,
       X.transform(4.0 * Vec2(std::cos(-2.0), std::sin(-2.0))));

  auto add3 = [&](const std::string& name, const Vec3& z, const SE3& x, const Vec3& p) {
    Case c{name,
           std::make_shared<PosePointFactor3>(poseKey(3), landmarkKey(5), z,
                                              randomInformation<3>(rng)),
           {}};
    c.values.insert(poseKey(3), x);
    c.values.insertPoint3(landmarkKey(5), p);
    cases.push_back(std::move(c));
  };
  for (int i = 0; i < 6; ++i)
    add3("PosePoint3 random" + std::to_string(i), Vec3(u(rng), u(rng), u(rng)), randomSE3(rng),
         Vec3(u(rng), u(rng), u(rng)));
  const SE3 Y = randomSE3(rng);
  add3("PosePoint3 landmark on the pose", Vec3(1, 2, 3), Y, Y.t);
  add3("PosePoint3 pose rotated by π", Vec3(1, 2, 3), rotationOnly(Vec3(0, 0, kPi)), Vec3(4, 5, 6));
  return cases;
}

std::vector<Case> allCases() {
  std::vector<Case> all;
  for (auto* gen : {&betweenSE2Cases, &betweenSE3Cases, &priorCases, &landmarkCases})
    for (auto& c : (*gen)()) all.push_back(std::move(c));
  return all;
}

// ---------------------------------------------------------------------------- Jacobians

TEST(FactorJacobians, BetweenSE2) {
  for (const Case& c : betweenSE2Cases()) checkJacobians(*c.factor, c.values, c.name);
}
TEST(FactorJacobians, BetweenSE3) {
  for (const Case& c : betweenSE3Cases()) checkJacobians(*c.factor, c.values, c.name);
}
TEST(FactorJacobians, Priors) {
  for (const Case& c : priorCases()) checkJacobians(*c.factor, c.values, c.name);
}
TEST(FactorJacobians, Landmarks) {
  for (const Case& c : landmarkCases()) checkJacobians(*c.factor, c.values, c.name);
}

TEST(FactorJacobians, EveryTypeCovered) {
  std::set<std::string> names;
  for (const Case& c : allCases()) names.insert(c.factor->typeName());
  EXPECT_EQ(names, (std::set<std::string>{"BetweenSE2", "BetweenSE3", "PriorSE2", "PriorSE3",
                                          "PriorPoint2", "PriorPoint3", "PosePoint2", "PosePoint3",
                                          "BearingRange2"}));
}

// The checker itself: a Jacobian off by 1e-4 in one entry must be caught.
class CorruptedFactor final : public Factor {
 public:
  CorruptedFactor(std::shared_ptr<Factor> inner, int key, int entry)
      : Factor({{inner->key(0), inner->varType(0)}, {inner->key(1), inner->varType(1)}},
               inner->dim(), inner->role()),
        inner_(std::move(inner)),
        key_(key),
        entry_(entry) {}
  void evaluate(const double* const* x, double* r, double* const* J) const override {
    inner_->evaluate(x, r, J);
    if (J != nullptr && J[key_] != nullptr) J[key_][entry_] += 1e-4;
  }
  std::unique_ptr<Factor> clone() const override {
    return std::make_unique<CorruptedFactor>(*this);
  }
  const char* typeName() const override { return "Corrupted"; }

 private:
  std::shared_ptr<Factor> inner_;
  int key_, entry_;
};

TEST(FactorJacobians, CheckerDetectsWrongJacobian) {
  for (const Case& c : betweenSE3Cases()) {
    for (int key : {0, 1}) {
      const CorruptedFactor bad(c.factor, key, 5 * 6 + 2);  // column 5 (rotation z), row 2
      EXPECT_NONFATAL_FAILURE(checkJacobians(bad, c.values, "corrupted"), "analytic");
    }
  }
  const Case c = landmarkCases().back();  // PosePoint3
  const CorruptedFactor bad(c.factor, 1, 4);
  EXPECT_NONFATAL_FAILURE(checkJacobians(bad, c.values, "corrupted"), "analytic");
}

// ------------------------------------------------------------------ zero at measurement

TEST(FactorResidual, ZeroAtMeasurement) {
  std::mt19937 rng(105);
  for (int trial = 0; trial < 10; ++trial) {
    const SE2 xi = randomSE2(rng), z2 = randomSE2(rng);
    const SE3 Xi = randomSE3(rng), Z3 = randomSE3(rng);
    std::uniform_real_distribution<double> u(-5.0, 5.0), b(-kPi, kPi), rr(0.5, 20.0);
    const Vec2 p2(u(rng), u(rng));
    const Vec3 p3(u(rng), u(rng), u(rng));
    const double bearing = b(rng), range = rr(rng);

    Values v;
    v.insert(poseKey(0), xi);
    v.insert(poseKey(1), xi * z2);
    v.insert(poseKey(10), Xi);
    v.insert(poseKey(11), Xi * Z3);
    v.insertPoint2(landmarkKey(0), xi.transform(p2));
    v.insertPoint3(landmarkKey(1), Xi.transform(p3));
    v.insertPoint2(landmarkKey(2),
                   xi.transform(range * Vec2(std::cos(bearing), std::sin(bearing))));
    v.insertPoint2(landmarkKey(3), p2);
    v.insertPoint3(landmarkKey(4), p3);

    std::vector<std::shared_ptr<Factor>> fs = {
        std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(1), z2, randomInformation<3>(rng)),
        std::make_shared<BetweenFactorSE3>(poseKey(10), poseKey(11), Z3, randomInformation<6>(rng)),
        std::make_shared<PriorFactorSE2>(poseKey(0), xi, randomInformation<3>(rng)),
        std::make_shared<PriorFactorSE3>(poseKey(10), Xi, randomInformation<6>(rng)),
        std::make_shared<PriorFactorPoint2>(landmarkKey(3), p2, randomInformation<2>(rng)),
        std::make_shared<PriorFactorPoint3>(landmarkKey(4), p3, randomInformation<3>(rng)),
        std::make_shared<PosePointFactor2>(poseKey(0), landmarkKey(0), p2,
                                           randomInformation<2>(rng)),
        std::make_shared<PosePointFactor3>(poseKey(10), landmarkKey(1), p3,
                                           randomInformation<3>(rng)),
        std::make_shared<BearingRangeFactor2>(poseKey(0), landmarkKey(2), Vec2(bearing, range),
                                              randomInformation<2>(rng)),
    };
    for (const auto& f : fs) {
      EXPECT_LT(f->whitenedError(v).norm(), 1e-9) << f->typeName();
      EXPECT_LT(f->chi2(v), 1e-18) << f->typeName();
    }
  }
}

TEST(FactorResidual, BearingRangeLandmarkOnThePoseIsFinite) {
  Values v;
  v.insert(poseKey(0), SE2(1.0, 2.0, 0.3));
  v.insertPoint2(landmarkKey(0), Vec2(1.0, 2.0));
  const BearingRangeFactor2 f(poseKey(0), landmarkKey(0), Vec2(0.5, 1.0),
                              Eigen::Matrix2d::Identity());
  const double* x[2] = {v.data(0), v.data(1)};
  double r[2];
  JacobianBlock j0, j1;
  double* J[2] = {j0.data(), j1.data()};
  f.evaluate(x, r, J);
  EXPECT_TRUE(std::isfinite(r[0]) && std::isfinite(r[1]));
  for (int i = 0; i < 6; ++i) EXPECT_TRUE(std::isfinite(j0[i]));
  for (int i = 0; i < 4; ++i) EXPECT_TRUE(std::isfinite(j1[i]));
  EXPECT_NEAR(r[1], -1.0, 1e-6);  // range residual 0 − 1
}

// ----------------------------------------------------------------- chi2, independently

TEST(FactorChi2, BetweenSE2MatchesG2oError) {
  std::mt19937 rng(106);
  for (int trial = 0; trial < 50; ++trial) {
    const SE2 xi = randomSE2(rng), xj = randomSE2(rng), z = randomSE2(rng);
    const Eigen::Matrix3d info = randomInformation<3>(rng);
    const BetweenFactorSE2 f(poseKey(0), poseKey(1), z, info);
    Values v;
    v.insert(poseKey(0), xi);
    v.insert(poseKey(1), xj);
    // g2o: e = (x, y, wrapped θ) of Z⁻¹·Xi⁻¹·Xj, from homogeneous matrices.
    const Eigen::Matrix3d T =
        homogeneous(z).inverse() * homogeneous(xi).inverse() * homogeneous(xj);
    const Eigen::Vector3d e(T(0, 2), T(1, 2), std::atan2(T(1, 0), T(0, 0)));
    EXPECT_NEAR(f.chi2(v), e.dot(info * e), 1e-9 * (1.0 + e.dot(info * e)));
    // Whitened with the upper Cholesky factor of Ω.
    const Eigen::Matrix3d U = info.llt().matrixU();
    EXPECT_LT((f.whitenedError(v) - U * e).norm(), 1e-10 * (1.0 + e.norm()));
  }
}

TEST(FactorChi2, BetweenSE3MatchesLogOfRelativeError) {
  std::mt19937 rng(107);
  for (int trial = 0; trial < 50; ++trial) {
    const SE3 Xi = randomSE3(rng), Z = randomSE3(rng);
    // Keep the residual rotation below π so Log is unique; include small and large ones.
    std::uniform_real_distribution<double> a(0.0, 3.0), u(-3.0, 3.0);
    const SE3 E(expSO3(randomUnit(rng) * (trial < 5 ? 1e-7 * trial : a(rng))),
                Vec3(u(rng), u(rng), u(rng)));
    const SE3 Xj = Xi * Z * E;
    const Mat6 info = randomInformation<6>(rng);
    const BetweenFactorSE3 f(poseKey(0), poseKey(1), Z, info);
    Values v;
    v.insert(poseKey(0), Xi);
    v.insert(poseKey(1), Xj);
    const Mat4 T = homogeneous(Z).inverse() * homogeneous(Xi).inverse() * homogeneous(Xj);
    const Vec6 e = referenceLogSE3(T);  // translation first
    EXPECT_NEAR(f.chi2(v), e.dot(info * e), 1e-8 * (1.0 + e.dot(info * e)));
    const Mat6 U = info.llt().matrixU();
    EXPECT_LT((f.whitenedError(v) - U * e).norm(), 1e-9 * (1.0 + e.norm()));
  }
}

TEST(FactorChi2, LandmarkAndPriorErrors) {
  std::mt19937 rng(108);
  std::uniform_real_distribution<double> u(-5.0, 5.0);
  for (int trial = 0; trial < 20; ++trial) {
    const SE2 x = randomSE2(rng), zx = randomSE2(rng);
    const SE3 X = randomSE3(rng);
    const Vec2 p(u(rng), u(rng)), z2(u(rng), u(rng)), br(0.5 * u(rng), std::abs(u(rng)));
    const Vec3 q(u(rng), u(rng), u(rng)), z3(u(rng), u(rng), u(rng));
    Values v;
    v.insert(poseKey(0), x);
    v.insert(poseKey(1), X);
    v.insertPoint2(landmarkKey(0), p);
    v.insertPoint3(landmarkKey(1), q);

    const Eigen::Matrix2d I2 = randomInformation<2>(rng);
    const Mat3 I3 = randomInformation<3>(rng);
    const Eigen::Vector2d e_pp2 = rot2(x.theta).transpose() * (p - x.t()) - z2;
    EXPECT_NEAR(PosePointFactor2(poseKey(0), landmarkKey(0), z2, I2).chi2(v), e_pp2.dot(I2 * e_pp2),
                1e-9);
    const Vec3 e_pp3 = X.R.transpose() * (q - X.t) - z3;
    EXPECT_NEAR(PosePointFactor3(poseKey(1), landmarkKey(1), z3, I3).chi2(v), e_pp3.dot(I3 * e_pp3),
                1e-8);
    const Vec2 lv = rot2(x.theta).transpose() * (p - x.t());
    const Eigen::Vector2d e_br(wrapAngle(std::atan2(lv.y(), lv.x()) - br[0]), lv.norm() - br[1]);
    EXPECT_NEAR(BearingRangeFactor2(poseKey(0), landmarkKey(0), br, I2).chi2(v),
                e_br.dot(I2 * e_br), 1e-9);
    const Eigen::Matrix3d Tp = homogeneous(zx).inverse() * homogeneous(x);
    const Eigen::Vector3d e_ps(Tp(0, 2), Tp(1, 2), std::atan2(Tp(1, 0), Tp(0, 0)));
    EXPECT_NEAR(PriorFactorSE2(poseKey(0), zx, I3).chi2(v), e_ps.dot(I3 * e_ps), 1e-9);
    const Vec2 e_p2 = p - z2;
    EXPECT_NEAR(PriorFactorPoint2(landmarkKey(0), z2, I2).chi2(v), e_p2.dot(I2 * e_p2), 1e-9);
  }
}

// -------------------------------------------------------------- information validation

template <int D>
void expectRejected(const Eigen::Matrix<double, D, D>& m, const char* what) {
  EXPECT_THROW(sqrtInformation<D>(m), std::invalid_argument) << what << "\n" << m;
}

TEST(SqrtInformation, AcceptsSpdAndFactorsIt) {
  std::mt19937 rng(109);
  auto check = [](const auto& info) {
    const auto U = sqrtInformation(info);
    EXPECT_LT((U.transpose() * U - info).norm(), 1e-12 * info.norm());
    for (int r = 0; r < U.rows(); ++r) {
      EXPECT_GT(U(r, r), 0.0);
      for (int c = 0; c < r; ++c) EXPECT_EQ(U(r, c), 0.0);
    }
  };
  for (int i = 0; i < 10; ++i) {
    check(randomInformation<2>(rng));
    check(randomInformation<3>(rng));
    check(randomInformation<6>(rng));
  }
  check(Eigen::Matrix<double, 1, 1>(4.0));
  EXPECT_DOUBLE_EQ(sqrtInformation<1>(Eigen::Matrix<double, 1, 1>(4.0))(0, 0), 2.0);
  // Typical g2o information: large, diagonal.
  check(Mat6(Vec6(500, 500, 500, 1e4, 1e4, 1e4).asDiagonal()));
}

TEST(SqrtInformation, RejectsBadMatrices) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  // Not positive definite.
  expectRejected<1>(Eigen::Matrix<double, 1, 1>(0.0), "zero");
  expectRejected<1>(Eigen::Matrix<double, 1, 1>(-1.0), "negative");
  expectRejected<2>(Eigen::Matrix2d::Zero(), "zero 2x2");
  expectRejected<3>(Eigen::Vector3d(1.0, -1.0, 1.0).asDiagonal().toDenseMatrix(),
                    "indefinite diag");
  expectRejected<3>(Eigen::Vector3d(1.0, 0.0, 1.0).asDiagonal().toDenseMatrix(), "singular diag");
  expectRejected<3>(-Eigen::Matrix3d::Identity(), "negative definite");
  Eigen::Matrix2d indef;
  indef << 1.0, 2.0, 2.0, 1.0;  // eigenvalues 3, −1
  expectRejected<2>(indef, "indefinite, positive diagonal");
  Mat6 rank5 = Mat6::Identity();
  rank5(5, 5) = 0.0;
  expectRejected<6>(rank5, "rank-deficient 6x6");
  Mat6 ones = Mat6::Ones();  // rank 1
  expectRejected<6>(ones, "rank-one 6x6");
  // Not symmetric.
  Eigen::Matrix3d ns = Eigen::Matrix3d::Identity() * 10.0;
  ns(0, 1) = 1.0;
  expectRejected<3>(ns, "non-symmetric");
  Mat6 upperOnly = Mat6::Identity() * 100.0;
  upperOnly(1, 4) = 5.0;  // g2o's upper triangle without the mirrored lower part
  expectRejected<6>(upperOnly, "upper triangle only");
  Eigen::Matrix2d ns2;
  ns2 << 2.0, 0.5, -0.5, 2.0;  // PD quadratic form but not symmetric
  expectRejected<2>(ns2, "skew part");
  // Not finite.
  Eigen::Matrix3d n3 = Eigen::Matrix3d::Identity();
  n3(1, 1) = nan;
  expectRejected<3>(n3, "NaN diagonal");
  Eigen::Matrix3d n3o = Eigen::Matrix3d::Identity();
  n3o(0, 2) = n3o(2, 0) = nan;
  expectRejected<3>(n3o, "NaN off-diagonal (symmetric)");
  Mat6 i6 = Mat6::Identity();
  i6(3, 3) = inf;
  expectRejected<6>(i6, "Inf");
  expectRejected<1>(Eigen::Matrix<double, 1, 1>(nan), "NaN 1x1");
  // Finite and positive definite, but beyond what a solve in doubles survives: 1e300 made the
  // server's graph unsolvable (χ² inf once a closure disagreed with the odometry).
  expectRejected<3>(Eigen::Matrix3d::Identity() * 1e300, "1e300");
  expectRejected<6>(Mat6(Vec6(1, 1, 1, 1, 1, 2 * kMaxInformation).asDiagonal()), "one axis");
  EXPECT_NO_THROW(sqrtInformation<3>(Eigen::Matrix3d::Identity() * kMaxInformation));
}

TEST(SqrtInformation, FactorConstructorsValidate) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  Eigen::Matrix3d bad3 = Eigen::Matrix3d::Identity();
  bad3(2, 2) = -1.0;
  Mat6 bad6 = Mat6::Identity();
  bad6(0, 5) = nan;
  Eigen::Matrix2d bad2 = Eigen::Matrix2d::Identity();
  bad2(0, 1) = 0.5;  // not symmetric
  EXPECT_THROW(BetweenFactorSE2(poseKey(0), poseKey(1), SE2(), bad3), std::invalid_argument);
  EXPECT_THROW(BetweenFactorSE3(poseKey(0), poseKey(1), SE3(), bad6), std::invalid_argument);
  EXPECT_THROW(PriorFactorSE2(poseKey(0), SE2(), bad3), std::invalid_argument);
  EXPECT_THROW(PriorFactorSE3(poseKey(0), SE3(), bad6), std::invalid_argument);
  EXPECT_THROW(PriorFactorPoint2(landmarkKey(0), Vec2::Zero(), bad2), std::invalid_argument);
  EXPECT_THROW(PriorFactorPoint3(landmarkKey(0), Vec3::Zero(), bad3), std::invalid_argument);
  EXPECT_THROW(PosePointFactor2(poseKey(0), landmarkKey(0), Vec2::Zero(), bad2),
               std::invalid_argument);
  EXPECT_THROW(PosePointFactor3(poseKey(0), landmarkKey(0), Vec3::Zero(), bad3),
               std::invalid_argument);
  EXPECT_THROW(BearingRangeFactor2(poseKey(0), landmarkKey(0), Vec2(0.0, 1.0), bad2),
               std::invalid_argument);
}

// ------------------------------------------------------------------- metadata and clone

TEST(Factor, MetadataAndRoles) {
  const BetweenFactorSE2 b(poseKey(1), poseKey(2), SE2(), Eigen::Matrix3d::Identity());
  EXPECT_EQ(b.size(), 2);
  EXPECT_EQ(b.dim(), 3);
  EXPECT_EQ(b.key(0), poseKey(1));
  EXPECT_EQ(b.key(1), poseKey(2));
  EXPECT_EQ(b.varType(0), VarType::SE2);
  EXPECT_EQ(b.role(), FactorRole::LoopClosure);
  EXPECT_TRUE(isUncertain(b.role()));
  const BetweenFactorSE3 o(poseKey(1), poseKey(2), SE3(), Mat6::Identity(), FactorRole::Odometry);
  EXPECT_EQ(o.dim(), 6);
  EXPECT_EQ(o.varType(1), VarType::SE3);
  EXPECT_EQ(o.role(), FactorRole::Odometry);
  EXPECT_FALSE(isUncertain(o.role()));
  const PriorFactorSE3 p(poseKey(0), SE3(), Mat6::Identity());
  EXPECT_EQ(p.size(), 1);
  EXPECT_EQ(p.role(), FactorRole::Prior);
  const BearingRangeFactor2 l(poseKey(0), landmarkKey(3), Vec2(0.0, 1.0),
                              Eigen::Matrix2d::Identity());
  EXPECT_EQ(l.role(), FactorRole::Landmark);
  EXPECT_EQ(l.varType(1), VarType::Point2);
  EXPECT_TRUE(isUncertain(l.role()));
  const PosePointFactor3 pp3(poseKey(0), landmarkKey(3), Vec3::Zero(), Mat3::Identity());
  EXPECT_EQ(pp3.dim(), 3);
  EXPECT_EQ(pp3.varType(0), VarType::SE3);
  EXPECT_EQ(pp3.varType(1), VarType::Point3);
  EXPECT_STREQ(factorRoleName(FactorRole::LoopClosure), "loop_closure");
  EXPECT_STREQ(
      PriorFactorPoint2(landmarkKey(0), Vec2::Zero(), Eigen::Matrix2d::Identity()).typeName(),
      "PriorPoint2");
  EXPECT_STREQ(PriorFactorPoint3(landmarkKey(0), Vec3::Zero(), Mat3::Identity()).typeName(),
               "PriorPoint3");
}

TEST(Factor, WhitenedErrorThrowsOnMissingKey) {
  const BetweenFactorSE2 b(poseKey(1), poseKey(2), SE2(), Eigen::Matrix3d::Identity());
  Values v;
  v.insert(poseKey(1), SE2());
  EXPECT_THROW(b.whitenedError(v), std::out_of_range);
  EXPECT_THROW(b.chi2(v), std::out_of_range);
}

// chi2 evaluates into a stack buffer (no allocation): the same bits as the whitened error's
// squared norm, from a Values or from the variables' storage directly.
TEST(Factor, Chi2IsTheWhitenedErrorsSquaredNormBitForBit) {
  const std::vector<Case> cases = allCases();
  size_t away = 0;  // cases not at their measurement (a zero chi2 would prove little)
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const Factor& f = *c.factor;
    const double expected = f.whitenedError(c.values).squaredNorm();
    EXPECT_EQ(f.chi2(c.values), expected);
    std::array<const double*, kMaxFactorKeys> x{};
    for (int i = 0; i < f.size(); ++i) x[i] = c.values.data(c.values.slot(f.key(i)));
    EXPECT_EQ(f.chi2(x.data()), expected);
    away += expected > 0.0 ? 1 : 0;
  }
  EXPECT_GT(away, cases.size() / 2);
}

TEST(Factor, CloneGivesSameResidualAndJacobians) {
  for (const Case& c : allCases()) {
    SCOPED_TRACE(c.name);
    c.factor->setId(1234567);
    c.factor->setRole(FactorRole::LoopClosure);
    std::unique_ptr<Factor> copy = c.factor->clone();
    ASSERT_NE(copy.get(), c.factor.get());
    EXPECT_STREQ(copy->typeName(), c.factor->typeName());
    EXPECT_EQ(copy->size(), c.factor->size());
    EXPECT_EQ(copy->dim(), c.factor->dim());
    EXPECT_EQ(copy->id(), 1234567u);
    EXPECT_EQ(copy->role(), FactorRole::LoopClosure);
    for (int i = 0; i < copy->size(); ++i) {
      EXPECT_EQ(copy->key(i), c.factor->key(i));
      EXPECT_EQ(copy->varType(i), c.factor->varType(i));
    }
    EXPECT_EQ(copy->whitenedError(c.values), c.factor->whitenedError(c.values));
    // The copy is independent of the original.
    c.factor->setId(1);
    EXPECT_EQ(copy->id(), 1234567u);
    checkJacobians(*copy, c.values, c.name + " (clone)");
  }
}

}  // namespace
}  // namespace loopd
