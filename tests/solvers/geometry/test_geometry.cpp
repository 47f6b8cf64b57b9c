// SO(3), SE(2), SE(3): group operations, Exp/Log, Jacobians (checked against central
// differences) and conversions.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <cmath>
#include <random>
#include <vector>

#include "solvers/geometry/se2.h"
#include "solvers/geometry/se3.h"
#include "solvers/geometry/so3.h"
#include "tests/solvers/geometry/matrix_forms.h"

namespace loopd {
namespace {

using test::homogeneous;
using test::randomUnit;

using Mat4 = Eigen::Matrix4d;

constexpr double kPi = M_PI;

Vec3 randomRotVec(std::mt19937& rng, double maxAngle) {
  std::uniform_real_distribution<double> u(0.0, maxAngle);
  return randomUnit(rng) * u(rng);
}

Vec6 randomTwist(std::mt19937& rng, double maxAngle, double maxTrans = 3.0) {
  std::uniform_real_distribution<double> u(-maxTrans, maxTrans);
  Vec6 xi;
  xi.head<3>() = Vec3(u(rng), u(rng), u(rng));
  xi.tail<3>() = randomRotVec(rng, maxAngle);
  return xi;
}

SE3 randomSE3(std::mt19937& rng) { return expSE3(randomTwist(rng, 3.0)); }

bool isRotation(const Mat3& R, double tol = 1e-12) {
  return (R.transpose() * R - Mat3::Identity()).norm() < tol &&
         std::abs(R.determinant() - 1.0) < tol;
}

// Independent dense matrix exponential: scaling and squaring with a Taylor series.
template <typename M>
M expm(const M& A) {
  int s = 0;
  double n = A.norm();
  while (n > 0.5) {
    n *= 0.5;
    ++s;
  }
  const M B = A / std::pow(2.0, s);
  M E = M::Identity(), term = M::Identity();
  for (int k = 1; k < 30; ++k) {
    term = term * B / static_cast<double>(k);
    E += term;
  }
  for (int i = 0; i < s; ++i) E = E * E;
  return E;
}

Mat4 twistMatrix(const Vec6& xi) {
  Mat4 T = Mat4::Zero();
  T.topLeftCorner<3, 3>() = hat(xi.tail<3>());
  T.topRightCorner<3, 1>() = xi.head<3>();
  return T;
}

// ---------------------------------------------------------------------------------- SO(3)

TEST(SO3, HatIsCrossProduct) {
  std::mt19937 rng(1);
  std::normal_distribution<double> n(0.0, 2.0);
  for (int i = 0; i < 20; ++i) {
    const Vec3 a(n(rng), n(rng), n(rng)), b(n(rng), n(rng), n(rng));
    EXPECT_LT((hat(a) * b - a.cross(b)).norm(), 1e-12);
    EXPECT_LT((hat(a) + hat(a).transpose()).norm(), 0.0 + 1e-15);
  }
}

TEST(SO3, ExpMatchesMatrixExponentialAndAngleAxis) {
  std::mt19937 rng(2);
  for (int i = 0; i < 50; ++i) {
    const Vec3 w = randomRotVec(rng, 3.1);
    const Mat3 R = expSO3(w);
    EXPECT_TRUE(isRotation(R));
    EXPECT_LT((R - expm<Mat3>(hat(w))).norm(), 1e-12);
    EXPECT_LT((R - Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix()).norm(), 1e-12);
  }
  EXPECT_LT((expSO3(Vec3::Zero()) - Mat3::Identity()).norm(), 1e-15);
}

TEST(SO3, ExpLogRoundTripRandom) {
  std::mt19937 rng(3);
  for (int i = 0; i < 200; ++i) {
    const Vec3 w = randomRotVec(rng, kPi - 1e-3);
    EXPECT_LT((logSO3(expSO3(w)) - w).norm(), 1e-12) << w.transpose();
    // And the other direction, for arbitrary rotations.
    const Mat3 R = expSO3(randomRotVec(rng, 10.0));
    const Vec3 l = logSO3(R);
    EXPECT_LE(l.norm(), kPi + 1e-12);
    EXPECT_LT((expSO3(l) - R).norm(), 1e-12);
  }
}

TEST(SO3, ExpLogTinyAngles) {
  std::mt19937 rng(4);
  for (double a : {1e-9, 1e-12, 1e-15, 3e-6, 1e-5}) {
    for (int i = 0; i < 10; ++i) {
      const Vec3 w = randomUnit(rng) * a;
      const Mat3 R = expSO3(w);
      EXPECT_TRUE(isRotation(R));
      const Vec3 l = logSO3(R);
      EXPECT_LT((l - w).norm(), 1e-7 * a + 1e-300) << "angle " << a;
      EXPECT_TRUE(l.allFinite());
    }
  }
  EXPECT_LT(logSO3(Mat3::Identity()).norm(), 1e-300);
  EXPECT_TRUE(logSO3(Mat3::Identity()).allFinite());
}

TEST(SO3, ExpLogNearPi) {
  std::mt19937 rng(5);
  for (double eps : {1e-2, 1e-4, 1e-6, 1e-9}) {
    for (int i = 0; i < 10; ++i) {
      const Vec3 w = randomUnit(rng) * (kPi - eps);
      const Mat3 R = expSO3(w);
      const Vec3 l = logSO3(R);
      EXPECT_TRUE(l.allFinite());
      EXPECT_LT((l - w).norm(), 1e-9) << "eps " << eps;
      EXPECT_LT((expSO3(l) - R).norm(), 1e-12);
    }
  }
  // Exactly π (about each axis and a generic one): Log is ±ω, Exp(Log R) = R.
  for (const Vec3& axis : std::vector<Vec3>{Vec3::UnitX(), Vec3::UnitY(), Vec3::UnitZ(),
                                            Vec3(1.0, -2.0, 0.5).normalized()}) {
    const Mat3 R = Eigen::AngleAxisd(kPi, axis).toRotationMatrix();
    const Vec3 l = logSO3(R);
    EXPECT_NEAR(l.norm(), kPi, 1e-9);
    EXPECT_NEAR(std::abs(l.normalized().dot(axis)), 1.0, 1e-9);
    EXPECT_LT((expSO3(l) - R).norm(), 1e-9);
  }
  // Just beyond π wraps to the other side.
  const Vec3 axis = Vec3(0.3, 0.4, -0.5).normalized();
  const Vec3 l = logSO3(expSO3(axis * (kPi + 0.1)));
  EXPECT_LT((l + axis * (kPi - 0.1)).norm(), 1e-12);
}

// Central difference of Log(Exp(w)ᵀ Exp(w + h e_k)) / h: columns of Jr(w).
Mat3 numericalJr(const Vec3& w, double h = 1e-6) {
  Mat3 J;
  const Mat3 RT = expSO3(w).transpose();
  for (int k = 0; k < 3; ++k) {
    const Vec3 d = Vec3::Unit(k) * h;
    J.col(k) = (logSO3(RT * expSO3(w + d)) - logSO3(RT * expSO3(w - d))) / (2.0 * h);
  }
  return J;
}

// Central difference of Log(Exp(w)·Exp(δ)) in δ: columns of Jr⁻¹(w).
Mat3 numericalJrInv(const Vec3& w, double h = 1e-6) {
  Mat3 J;
  const Mat3 R = expSO3(w);
  for (int k = 0; k < 3; ++k) {
    const Vec3 d = Vec3::Unit(k) * h;
    J.col(k) = (logSO3(R * expSO3(d)) - logSO3(R * expSO3(-d))) / (2.0 * h);
  }
  return J;
}

std::vector<Vec3> jacobianTestPoints() {
  std::mt19937 rng(6);
  std::vector<Vec3> pts;
  pts.push_back(Vec3::Zero());
  for (double a : {1e-9, 1e-6, 1e-5, 1e-4, 9e-4, 1.1e-3, 0.01, 0.5, 1.0, 2.0, 2.8, 3.0, 3.1})
    for (int i = 0; i < 4; ++i) pts.push_back(randomUnit(rng) * a);
  for (int i = 0; i < 30; ++i) pts.push_back(randomRotVec(rng, 3.0));
  return pts;
}

TEST(SO3, RightJacobianMatchesNumerical) {
  for (const Vec3& w : jacobianTestPoints()) {
    const Mat3 Jr = rightJacobianSO3(w);
    EXPECT_LT((Jr - numericalJr(w)).norm(), 1e-7) << "w = " << w.transpose();
    // First-order identity Exp(w + δ) ≈ Exp(w)·Exp(Jr δ).
    const Vec3 d(1e-7, -2e-7, 3e-7);
    EXPECT_LT((expSO3(w + d) - expSO3(w) * expSO3(Jr * d)).norm(), 1e-12);
  }
}

TEST(SO3, RightJacobianInverseMatchesNumerical) {
  for (const Vec3& w : jacobianTestPoints()) {
    const Mat3 JrInv = rightJacobianInverseSO3(w);
    const Mat3 num = numericalJrInv(w);
    EXPECT_LT((JrInv - num).norm(), 1e-7 * (1.0 + num.norm())) << "w = " << w.transpose();
    EXPECT_LT((JrInv * rightJacobianSO3(w) - Mat3::Identity()).norm(), 1e-10)
        << "w = " << w.transpose();
  }
}

TEST(SO3, ProjectToSO3) {
  std::mt19937 rng(7);
  std::normal_distribution<double> n(0.0, 1.0);
  for (int i = 0; i < 30; ++i) {
    const Mat3 R = expSO3(randomRotVec(rng, 3.1));
    // A rotation is its own projection.
    EXPECT_LT((projectToSO3(R) - R).norm(), 1e-12);
    // Polar decomposition: M = R·S with S symmetric positive definite projects to R.
    Mat3 A;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) A(r, c) = 0.1 * n(rng);
    const Mat3 S = Mat3::Identity() + 0.5 * (A + A.transpose()) * 0.5;
    ASSERT_GT(Eigen::SelfAdjointEigenSolver<Mat3>(S).eigenvalues().minCoeff(), 0.0);
    EXPECT_LT((projectToSO3(R * S) - R).norm(), 1e-10);
    // Scale does not matter.
    EXPECT_LT((projectToSO3(3.7 * R) - R).norm(), 1e-12);
    // Arbitrary matrices, including reflections, give a proper rotation.
    Mat3 M;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) M(r, c) = n(rng);
    EXPECT_TRUE(isRotation(projectToSO3(M), 1e-10));
    EXPECT_TRUE(isRotation(projectToSO3(-R), 1e-10));
  }
}

// ---------------------------------------------------------------------------------- SE(2)

TEST(SE2, WrapAngleEdgeCases) {
  EXPECT_DOUBLE_EQ(wrapAngle(0.0), 0.0);
  EXPECT_DOUBLE_EQ(wrapAngle(kPi), kPi);   // (−π, π]: π stays
  EXPECT_DOUBLE_EQ(wrapAngle(-kPi), kPi);  // −π maps to π
  EXPECT_NEAR(wrapAngle(2.0 * kPi), 0.0, 1e-15);
  EXPECT_NEAR(wrapAngle(-2.0 * kPi), 0.0, 1e-15);
  EXPECT_NEAR(wrapAngle(kPi + 1e-9), -kPi + 1e-9, 1e-15);
  EXPECT_NEAR(wrapAngle(-kPi - 1e-9), kPi - 1e-9, 1e-15);
  EXPECT_NEAR(wrapAngle(kPi - 1e-9), kPi - 1e-9, 1e-15);
  EXPECT_NEAR(wrapAngle(-kPi + 1e-9), -kPi + 1e-9, 1e-15);
  EXPECT_NEAR(std::abs(wrapAngle(3.0 * kPi)), kPi, 1e-12);
  EXPECT_NEAR(std::abs(wrapAngle(-3.0 * kPi)), kPi, 1e-12);
  EXPECT_NEAR(wrapAngle(1.5 * kPi), -0.5 * kPi, 1e-15);
  EXPECT_NEAR(wrapAngle(-1.5 * kPi), 0.5 * kPi, 1e-15);
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(-100.0, 100.0);
  for (int i = 0; i < 1000; ++i) {
    const double a = u(rng);
    const double w = wrapAngle(a);
    EXPECT_GT(w, -kPi);
    EXPECT_LE(w, kPi);
    EXPECT_NEAR(std::cos(w), std::cos(a), 1e-12);
    EXPECT_NEAR(std::sin(w), std::sin(a), 1e-12);
    EXPECT_NEAR(wrapAngle(w), w, 1e-15);
  }
}

TEST(SE2, ComposeInverseBetweenMatchHomogeneousMatrices) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-5.0, 5.0), a(-kPi, kPi);
  for (int i = 0; i < 100; ++i) {
    const SE2 A(u(rng), u(rng), a(rng)), B(u(rng), u(rng), a(rng));
    const SE2 AB = A * B;
    const Eigen::Matrix3d T = homogeneous(A) * homogeneous(B);
    EXPECT_LT((homogeneous(AB) - T).norm(), 1e-12);
    EXPECT_GT(AB.theta, -kPi);
    EXPECT_LE(AB.theta, kPi);

    const SE2 Ai = A.inverse();
    EXPECT_LT((homogeneous(Ai) - homogeneous(A).inverse()).norm(), 1e-12);
    const SE2 I = A * Ai;
    EXPECT_NEAR(I.x, 0.0, 1e-12);
    EXPECT_NEAR(I.y, 0.0, 1e-12);
    EXPECT_NEAR(I.theta, 0.0, 1e-12);

    const SE2 D = A.between(B);
    EXPECT_LT((homogeneous(D) - homogeneous(A).inverse() * homogeneous(B)).norm(), 1e-12);
    const SE2 B2 = A * D;
    EXPECT_NEAR(B2.x, B.x, 1e-12);
    EXPECT_NEAR(B2.y, B.y, 1e-12);
    EXPECT_NEAR(wrapAngle(B2.theta - B.theta), 0.0, 1e-12);

    const Vec2 p(u(rng), u(rng));
    EXPECT_LT((A.transformTo(A.transform(p)) - p).norm(), 1e-12);
    EXPECT_LT((A.transform(p) - (homogeneous(A) * p.homogeneous()).head<2>()).norm(), 1e-12);

    const Eigen::Vector3d d(0.1 * u(rng), 0.1 * u(rng), 0.1 * a(rng));
    const SE2 Ar = A.retract(d);
    EXPECT_LT((homogeneous(Ar) - homogeneous(A) * homogeneous(SE2(d.x(), d.y(), d.z()))).norm(),
              1e-12);
  }
}

TEST(SE2, ComposeWrapsAcrossPi) {
  const SE2 A(1.0, 2.0, kPi - 0.1), B(0.0, 0.0, 0.2);
  const SE2 C = A * B;
  EXPECT_NEAR(C.theta, -kPi + 0.1, 1e-12);
  const SE2 D(0.0, 0.0, -kPi + 0.05);
  const SE2 E = D.between(A);  // θ difference π − 0.15 − ... = (π−0.1) − (−π+0.05) = 2π − 0.15
  EXPECT_NEAR(E.theta, -0.15, 1e-12);
  // π composed with π is 0, and the inverse of θ = π is θ = ±π (same rotation).
  const SE2 P(0.0, 0.0, kPi);
  EXPECT_NEAR((P * P).theta, 0.0, 1e-12);
  EXPECT_NEAR(std::abs(wrapAngle(P.inverse().theta)), kPi, 1e-12);
  EXPECT_NEAR((P * P.inverse()).theta, 0.0, 1e-12);
}

// ---------------------------------------------------------------------------------- SE(3)

TEST(SE3, ComposeInverseBetweenMatchHomogeneousMatrices) {
  std::mt19937 rng(10);
  std::uniform_real_distribution<double> u(-5.0, 5.0);
  for (int i = 0; i < 50; ++i) {
    const SE3 A = randomSE3(rng), B = randomSE3(rng);
    EXPECT_LT((homogeneous(A * B) - homogeneous(A) * homogeneous(B)).norm(), 1e-12);
    EXPECT_LT((homogeneous(A.inverse()) - homogeneous(A).inverse()).norm(), 1e-11);
    EXPECT_LT((homogeneous(A.between(B)) - homogeneous(A).inverse() * homogeneous(B)).norm(),
              1e-11);
    EXPECT_LT((homogeneous(A * A.inverse()) - Mat4::Identity()).norm(), 1e-12);
    const Vec3 p(u(rng), u(rng), u(rng));
    EXPECT_LT((A.transform(p) - (homogeneous(A) * p.homogeneous()).head<3>()).norm(), 1e-12);
    EXPECT_LT((A.transformTo(A.transform(p)) - p).norm(), 1e-12);
  }
}

TEST(SE3, ExpMatchesMatrixExponential) {
  std::mt19937 rng(11);
  for (int i = 0; i < 50; ++i) {
    const Vec6 xi = randomTwist(rng, 3.1);
    EXPECT_LT((homogeneous(expSE3(xi)) - expm<Mat4>(twistMatrix(xi))).norm(), 1e-10)
        << xi.transpose();
  }
  for (double a : {0.0, 1e-12, 1e-8, 1e-4}) {
    Vec6 xi;
    xi << 1.0, -2.0, 0.5, a, -a, 0.5 * a;
    EXPECT_LT((homogeneous(expSE3(xi)) - expm<Mat4>(twistMatrix(xi))).norm(), 1e-12);
  }
}

TEST(SE3, ExpLogRoundTrip) {
  std::mt19937 rng(12);
  std::vector<Vec6> xis;
  for (int i = 0; i < 100; ++i) xis.push_back(randomTwist(rng, kPi - 1e-3));
  for (double a : {0.0, 1e-12, 1e-9, 1e-6, 1e-3, 3.0, 3.1, kPi - 1e-6}) {
    for (int i = 0; i < 3; ++i) {
      Vec6 xi = randomTwist(rng, 1.0);
      xi.tail<3>() = randomUnit(rng) * a;
      xis.push_back(xi);
    }
  }
  for (const Vec6& xi : xis) {
    const SE3 X = expSE3(xi);
    EXPECT_TRUE(isRotation(X.R));
    const Vec6 l = logSE3(X);
    EXPECT_LT((l - xi).norm(), 1e-9) << xi.transpose();
    EXPECT_LT((homogeneous(expSE3(l)) - homogeneous(X)).norm(), 1e-10);
  }
}

TEST(SE3, AdjointIdentity) {
  std::mt19937 rng(13);
  for (int i = 0; i < 50; ++i) {
    const SE3 X = randomSE3(rng);
    const Vec6 xi = randomTwist(rng, 2.0, 1.0);
    const Mat4 lhs = homogeneous(X * expSE3(xi) * X.inverse());
    const Mat4 rhs = homogeneous(expSE3(X.adjoint() * xi));
    EXPECT_LT((lhs - rhs).norm(), 1e-10);
    // Ad is a homomorphism, and Ad(X⁻¹) = Ad(X)⁻¹.
    const SE3 Y = randomSE3(rng);
    EXPECT_LT(((X * Y).adjoint() - X.adjoint() * Y.adjoint()).norm(), 1e-10);
    EXPECT_LT((X.inverse().adjoint() * X.adjoint() - Mat6::Identity()).norm(), 1e-10);
  }
}

TEST(SE3, RetractIsFirstOrderRightExp) {
  std::mt19937 rng(14);
  for (int i = 0; i < 20; ++i) {
    const SE3 X = randomSE3(rng);
    const Vec6 d = randomTwist(rng, 1.0, 1.0) * 1e-5;
    const SE3 A = X.retract(d), B = X * expSE3(d);
    EXPECT_LT((homogeneous(A) - homogeneous(B)).norm(), 1e-8);
    EXPECT_LT((A.R - X.R * expSO3(d.tail<3>())).norm(), 1e-15);
    EXPECT_LT((A.t - (X.t + X.R * d.head<3>())).norm(), 1e-14);
  }
}

// Central difference of Log(Exp(ξ)·Exp(δ)) in δ at δ = 0.
Mat6 numericalJrInvSE3(const Vec6& xi, double h = 1e-6) {
  Mat6 J;
  const SE3 X = expSE3(xi);
  for (int k = 0; k < 6; ++k) {
    const Vec6 d = Vec6::Unit(k) * h;
    J.col(k) = (logSE3(X * expSE3(d)) - logSE3(X * expSE3(-d))) / (2.0 * h);
  }
  return J;
}

TEST(SE3, RightJacobianInverseMatchesNumerical) {
  std::mt19937 rng(15);
  std::vector<Vec6> xis;
  for (int i = 0; i < 40; ++i) xis.push_back(randomTwist(rng, 3.0));
  // |φ| near 0 (including both sides of the series switch in the Q block) and near 3.
  for (double a : {0.0, 1e-10, 1e-7, 1e-5, 1e-4, 9.9e-4, 1.01e-3, 1e-2, 2.9, 2.99, 3.0, 3.05}) {
    for (int i = 0; i < 4; ++i) {
      Vec6 xi = randomTwist(rng, 1.0);
      xi.tail<3>() = randomUnit(rng) * a;
      xis.push_back(xi);
    }
  }
  for (const Vec6& xi : xis) {
    const Mat6 an = rightJacobianInverseSE3(xi);
    const Mat6 num = numericalJrInvSE3(xi);
    EXPECT_LT((an - num).norm(), 1e-6 * (1.0 + num.norm()))
        << "xi = " << xi.transpose() << "\nanalytic\n"
        << an << "\nnumerical\n"
        << num;
    // First-order identity with a small step.
    const Vec6 d = randomTwist(rng, 1.0, 1.0) * 1e-7;
    EXPECT_LT((logSE3(expSE3(xi) * expSE3(d)) - (xi + an * d)).norm(), 1e-11) << xi.transpose();
  }
}

TEST(SE3, TranslationQuaternionRoundTrip) {
  std::mt19937 rng(16);
  for (int i = 0; i < 50; ++i) {
    const SE3 X = randomSE3(rng);
    double v[7];
    X.toTranslationQuaternion(v);
    EXPECT_GE(v[6], 0.0);
    EXPECT_NEAR(Eigen::Vector4d(v[3], v[4], v[5], v[6]).norm(), 1.0, 1e-12);
    EXPECT_DOUBLE_EQ(v[0], X.t.x());
    EXPECT_DOUBLE_EQ(v[1], X.t.y());
    EXPECT_DOUBLE_EQ(v[2], X.t.z());
    const SE3 Y = SE3::fromTranslationQuaternion(v);
    EXPECT_LT((Y.R - X.R).norm(), 1e-12);
    EXPECT_LT((Y.t - X.t).norm(), 1e-15);
    // Matches Eigen's quaternion convention (x, y, z, w storage order).
    const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
    EXPECT_LT((q.toRotationMatrix() - X.R).norm(), 1e-12);
  }
  // Unnormalised and sign-flipped quaternions give the same rotation; output has qw ≥ 0.
  const Eigen::Quaterniond q = Eigen::Quaterniond(0.3, -0.5, 0.2, 0.7).normalized();
  const double a[7] = {1.0, 2.0, 3.0, 4.0 * q.x(), 4.0 * q.y(), 4.0 * q.z(), 4.0 * q.w()};
  const double b[7] = {1.0, 2.0, 3.0, -q.x(), -q.y(), -q.z(), -q.w()};
  const SE3 A = SE3::fromTranslationQuaternion(a), B = SE3::fromTranslationQuaternion(b);
  EXPECT_TRUE(isRotation(A.R));
  EXPECT_LT((A.R - q.toRotationMatrix()).norm(), 1e-12);
  EXPECT_LT((B.R - q.toRotationMatrix()).norm(), 1e-12);
  double out[7];
  B.toTranslationQuaternion(out);
  EXPECT_NEAR(out[3], q.x(), 1e-12);
  EXPECT_NEAR(out[4], q.y(), 1e-12);
  EXPECT_NEAR(out[5], q.z(), 1e-12);
  EXPECT_NEAR(out[6], q.w(), 1e-12);
  // Rotation by π: qw = 0, still a valid unit quaternion that round-trips.
  const SE3 P(Eigen::AngleAxisd(kPi, Vec3(1.0, 1.0, 0.0).normalized()).toRotationMatrix(),
              Vec3(0.5, 0.0, -1.0));
  P.toTranslationQuaternion(out);
  EXPECT_NEAR(out[6], 0.0, 1e-12);
  EXPECT_GE(out[6], 0.0);
  EXPECT_LT((SE3::fromTranslationQuaternion(out).R - P.R).norm(), 1e-12);
}

}  // namespace
}  // namespace loopd
