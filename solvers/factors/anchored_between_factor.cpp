#include "solvers/factors/anchored_between_factor.h"

namespace loopd {

namespace {
// Evaluates inner (a between factor of dimension D) at the common-frame poses p = A_r·x_r,
// q = A_s·x_s and chains its Jacobians onto (A_r, x_r, A_s, x_s): ∂e/∂δA = ∂e/∂δP·Ad(x⁻¹),
// ∂e/∂δx = ∂e/∂δP. adjointR() / adjointS() give Ad(x_r⁻¹) / Ad(x_s⁻¹), only when needed.
template <int D, class Inner, class AdjointR, class AdjointS>
void evaluateAnchored(const Inner& inner, const double* p, const double* q, double* r,
                      double* const* J, AdjointR adjointR, AdjointS adjointS) {
  using MatD = Eigen::Matrix<double, D, D>;
  const double* pq[2] = {p, q};
  if (J == nullptr) {
    inner.evaluate(pq, r, nullptr);
    return;
  }
  JacobianBlock jp{}, jq{};
  double* jpq[2] = {jp.data(), jq.data()};
  inner.evaluate(pq, r, jpq);
  const Eigen::Map<const MatD> JP(jp.data()), JQ(jq.data());
  if (J[0]) {
    Eigen::Map<MatD> out(J[0]);
    out = JP * adjointR();
  }
  if (J[1]) {
    Eigen::Map<MatD> out(J[1]);
    out = JP;
  }
  if (J[2]) {
    Eigen::Map<MatD> out(J[2]);
    out = JQ * adjointS();
  }
  if (J[3]) {
    Eigen::Map<MatD> out(J[3]);
    out = JQ;
  }
}
}  // namespace

Eigen::Matrix3d adjointSE2(const SE2& X) {
  Eigen::Matrix3d A = Eigen::Matrix3d::Identity();
  A.topLeftCorner<2, 2>() = X.R();
  A(0, 2) = X.y;
  A(1, 2) = -X.x;
  return A;
}

AnchoredBetweenFactorSE2::AnchoredBetweenFactorSE2(Key anchorR, Key poseR, Key anchorS, Key poseS,
                                                   const SE2& measured,
                                                   const Eigen::Matrix3d& information,
                                                   FactorRole role)
    : Factor({{anchorR, VarType::SE2},
              {poseR, VarType::SE2},
              {anchorS, VarType::SE2},
              {poseS, VarType::SE2}},
             3, role),
      inner_(poseR, poseS, measured, information, role) {}

void AnchoredBetweenFactorSE2::evaluate(const double* const* x, double* r, double* const* J) const {
  const SE2 ar(x[0][0], x[0][1], x[0][2]), xr(x[1][0], x[1][1], x[1][2]);
  const SE2 as(x[2][0], x[2][1], x[2][2]), xs(x[3][0], x[3][1], x[3][2]);
  const SE2 P = ar * xr, Q = as * xs;
  const double p[3] = {P.x, P.y, P.theta}, q[3] = {Q.x, Q.y, Q.theta};
  evaluateAnchored<3>(
      inner_, p, q, r, J, [&] { return adjointSE2(xr.inverse()); },
      [&] { return adjointSE2(xs.inverse()); });
}

std::unique_ptr<Factor> AnchoredBetweenFactorSE2::clone() const {
  return std::make_unique<AnchoredBetweenFactorSE2>(*this);
}

AnchoredBetweenFactorSE3::AnchoredBetweenFactorSE3(Key anchorR, Key poseR, Key anchorS, Key poseS,
                                                   const SE3& measured, const Mat6& information,
                                                   FactorRole role)
    : Factor({{anchorR, VarType::SE3},
              {poseR, VarType::SE3},
              {anchorS, VarType::SE3},
              {poseS, VarType::SE3}},
             6, role),
      inner_(poseR, poseS, measured, information, role) {}

namespace {
SE3 se3At(const double* d) { return {Eigen::Map<const Mat3>(d), Eigen::Map<const Vec3>(d + 9)}; }
void store(const SE3& X, double* d) {
  Eigen::Map<Mat3> R(d);
  Eigen::Map<Vec3> t(d + 9);
  R = X.R;
  t = X.t;
}
}  // namespace

void AnchoredBetweenFactorSE3::evaluate(const double* const* x, double* r, double* const* J) const {
  const SE3 ar = se3At(x[0]), xr = se3At(x[1]), as = se3At(x[2]), xs = se3At(x[3]);
  double p[kValueStride], q[kValueStride];
  store(ar * xr, p);
  store(as * xs, q);
  evaluateAnchored<6>(
      inner_, p, q, r, J, [&] { return xr.inverse().adjoint(); },
      [&] { return xs.inverse().adjoint(); });
}

std::unique_ptr<Factor> AnchoredBetweenFactorSE3::clone() const {
  return std::make_unique<AnchoredBetweenFactorSE3>(*this);
}

}  // namespace loopd
