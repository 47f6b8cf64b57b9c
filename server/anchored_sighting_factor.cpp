#include "server/anchored_sighting_factor.h"

#include "solvers/factors/anchored_between_factor.h"

namespace loopd::server {

namespace {
// Evaluates inner (a pose–point factor of dimension D over a pose of tangent dimension PD) at
// (P', l_s) and chains its pose Jacobian onto (A_r, x_r, A_s): ∂e/∂δA_r = ∂e/∂δP'·Ad(x_r⁻¹),
// ∂e/∂δx_r = ∂e/∂δP', ∂e/∂δA_s = −∂e/∂δP'·Ad(P'⁻¹); the point Jacobian is inner's own.
// adjointR() / adjointS() give Ad(x_r⁻¹) / Ad(P'⁻¹), only when needed.
template <int D, int PD, class Inner, class AdjointR, class AdjointS>
void evaluateSighting(const Inner& inner, const double* pose, const double* point, double* r,
                      double* const* J, AdjointR adjointR, AdjointS adjointS) {
  using MatP = Eigen::Matrix<double, D, PD>;
  const double* pl[2] = {pose, point};
  if (J == nullptr) {
    inner.evaluate(pl, r, nullptr);
    return;
  }
  JacobianBlock jp{};
  const bool needPose = J[0] != nullptr || J[1] != nullptr || J[2] != nullptr;
  double* jpl[2] = {needPose ? jp.data() : nullptr, J[3]};
  inner.evaluate(pl, r, jpl);
  if (!needPose) return;
  const Eigen::Map<const MatP> JP(jp.data());
  if (J[0]) {
    Eigen::Map<MatP> out(J[0]);
    out = JP * adjointR();
  }
  if (J[1]) {
    Eigen::Map<MatP> out(J[1]);
    out = JP;
  }
  if (J[2]) {
    Eigen::Map<MatP> out(J[2]);
    out = -(JP * adjointS());
  }
}

SE2 se2At(const double* d) { return {d[0], d[1], d[2]}; }
SE3 se3At(const double* d) { return {Eigen::Map<const Mat3>(d), Eigen::Map<const Vec3>(d + 9)}; }

// The sighting pose in s's frame, P' = A_s⁻¹·A_r·x_r, evaluated on 2D storage and chained.
template <class Inner>
void evaluateSighting2(const Inner& inner, const double* const* x, double* r, double* const* J) {
  const SE2 ar = se2At(x[0]), xr = se2At(x[1]), as = se2At(x[2]);
  const SE2 P = as.inverse() * (ar * xr);
  const double p[3] = {P.x, P.y, P.theta};
  evaluateSighting<2, 3>(
      inner, p, x[3], r, J, [&] { return adjointSE2(xr.inverse()); },
      [&] { return adjointSE2(P.inverse()); });
}
}  // namespace

template <>
const char* AnchoredSighting2<PosePointFactor2>::typeName() const {
  return "AnchoredPosePoint2";
}
template <>
const char* AnchoredSighting2<BearingRangeFactor2>::typeName() const {
  return "AnchoredBearingRange2";
}

template <class Inner>
AnchoredSighting2<Inner>::AnchoredSighting2(Key anchorR, Key poseR, Key anchorS, Key landmarkS,
                                            const Vec2& measured,
                                            const Eigen::Matrix2d& information, FactorRole role)
    : Factor({{anchorR, VarType::SE2},
              {poseR, VarType::SE2},
              {anchorS, VarType::SE2},
              {landmarkS, VarType::Point2}},
             2, role),
      inner_(poseR, landmarkS, measured, information, role) {}

template <class Inner>
void AnchoredSighting2<Inner>::evaluate(const double* const* x, double* r, double* const* J) const {
  evaluateSighting2(inner_, x, r, J);
}

template <class Inner>
std::unique_ptr<Factor> AnchoredSighting2<Inner>::clone() const {
  return std::make_unique<AnchoredSighting2<Inner>>(*this);
}

template class AnchoredSighting2<PosePointFactor2>;
template class AnchoredSighting2<BearingRangeFactor2>;

AnchoredPosePointFactor3::AnchoredPosePointFactor3(Key anchorR, Key poseR, Key anchorS,
                                                   Key landmarkS, const Vec3& measured,
                                                   const Mat3& information, FactorRole role)
    : Factor({{anchorR, VarType::SE3},
              {poseR, VarType::SE3},
              {anchorS, VarType::SE3},
              {landmarkS, VarType::Point3}},
             3, role),
      inner_(poseR, landmarkS, measured, information, role) {}

void AnchoredPosePointFactor3::evaluate(const double* const* x, double* r, double* const* J) const {
  const SE3 ar = se3At(x[0]), xr = se3At(x[1]), as = se3At(x[2]);
  const SE3 P = as.inverse() * (ar * xr);
  double p[kValueStride];
  Eigen::Map<Mat3> pR(p);
  Eigen::Map<Vec3> pt(p + 9);
  pR = P.R;
  pt = P.t;
  evaluateSighting<3, 6>(
      inner_, p, x[3], r, J, [&] { return xr.inverse().adjoint(); },
      [&] { return P.inverse().adjoint(); });
}

std::unique_ptr<Factor> AnchoredPosePointFactor3::clone() const {
  return std::make_unique<AnchoredPosePointFactor3>(*this);
}

}  // namespace loopd::server
