#include "server/anchored_between_factor.h"

namespace loopd::server {

Eigen::Matrix3d adjointSE2(const SE2& X) {
  Eigen::Matrix3d A = Eigen::Matrix3d::Identity();
  A.topLeftCorner<2, 2>() = X.R();
  A(0, 2) = X.y;
  A(1, 2) = -X.x;
  return A;
}

AnchoredBetweenFactorSE2::AnchoredBetweenFactorSE2(Key anchorR, Key poseR, Key anchorS,
                                                   Key poseS, const SE2& measured,
                                                   const Eigen::Matrix3d& information,
                                                   FactorRole role)
    : Factor({{anchorR, VarType::SE2}, {poseR, VarType::SE2}, {anchorS, VarType::SE2},
              {poseS, VarType::SE2}},
             3, role),
      inner_(poseR, poseS, measured, information, role) {}

void AnchoredBetweenFactorSE2::evaluate(const double* const* x, double* r,
                                        double* const* J) const {
  const SE2 ar(x[0][0], x[0][1], x[0][2]), xr(x[1][0], x[1][1], x[1][2]);
  const SE2 as(x[2][0], x[2][1], x[2][2]), xs(x[3][0], x[3][1], x[3][2]);
  const SE2 P = ar * xr, Q = as * xs;
  const double p[3] = {P.x, P.y, P.theta}, q[3] = {Q.x, Q.y, Q.theta};
  const double* pq[2] = {p, q};
  if (J == nullptr) {
    inner_.evaluate(pq, r, nullptr);
    return;
  }
  JacobianBlock jp{}, jq{};
  double* jpq[2] = {jp.data(), jq.data()};
  inner_.evaluate(pq, r, jpq);
  const Eigen::Map<const Eigen::Matrix3d> JP(jp.data()), JQ(jq.data());
  if (J[0]) { Eigen::Map<Eigen::Matrix3d> out(J[0]); out = JP * adjointSE2(xr.inverse()); }
  if (J[1]) { Eigen::Map<Eigen::Matrix3d> out(J[1]); out = JP; }
  if (J[2]) { Eigen::Map<Eigen::Matrix3d> out(J[2]); out = JQ * adjointSE2(xs.inverse()); }
  if (J[3]) { Eigen::Map<Eigen::Matrix3d> out(J[3]); out = JQ; }
}

std::unique_ptr<Factor> AnchoredBetweenFactorSE2::clone() const {
  return std::make_unique<AnchoredBetweenFactorSE2>(*this);
}

AnchoredBetweenFactorSE3::AnchoredBetweenFactorSE3(Key anchorR, Key poseR, Key anchorS,
                                                   Key poseS, const SE3& measured,
                                                   const Mat6& information, FactorRole role)
    : Factor({{anchorR, VarType::SE3}, {poseR, VarType::SE3}, {anchorS, VarType::SE3},
              {poseS, VarType::SE3}},
             6, role),
      inner_(poseR, poseS, measured, information, role) {}

namespace {
SE3 se3At(const double* d) {
  return {Eigen::Map<const Mat3>(d), Eigen::Map<const Vec3>(d + 9)};
}
void store(const SE3& X, double* d) {
  Eigen::Map<Mat3> R(d);
  Eigen::Map<Vec3> t(d + 9);
  R = X.R;
  t = X.t;
}
}  // namespace

void AnchoredBetweenFactorSE3::evaluate(const double* const* x, double* r,
                                        double* const* J) const {
  const SE3 ar = se3At(x[0]), xr = se3At(x[1]), as = se3At(x[2]), xs = se3At(x[3]);
  double p[kValueStride], q[kValueStride];
  store(ar * xr, p);
  store(as * xs, q);
  const double* pq[2] = {p, q};
  if (J == nullptr) {
    inner_.evaluate(pq, r, nullptr);
    return;
  }
  JacobianBlock jp{}, jq{};
  double* jpq[2] = {jp.data(), jq.data()};
  inner_.evaluate(pq, r, jpq);
  const Eigen::Map<const Mat6> JP(jp.data()), JQ(jq.data());
  if (J[0]) { Eigen::Map<Mat6> out(J[0]); out = JP * xr.inverse().adjoint(); }
  if (J[1]) { Eigen::Map<Mat6> out(J[1]); out = JP; }
  if (J[2]) { Eigen::Map<Mat6> out(J[2]); out = JQ * xs.inverse().adjoint(); }
  if (J[3]) { Eigen::Map<Mat6> out(J[3]); out = JQ; }
}

std::unique_ptr<Factor> AnchoredBetweenFactorSE3::clone() const {
  return std::make_unique<AnchoredBetweenFactorSE3>(*this);
}

}  // namespace loopd::server
