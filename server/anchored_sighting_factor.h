#pragma once
// Inter-robot landmark sightings through anchors: robot r's pose x_r sights a landmark l_s
// owned by robot s ≠ r, whose coordinates are in s's own frame. Anchors A_r, A_s place the
// robots' frames in the common one, so the sighting pose expressed in s's frame is
//   P' = A_s⁻¹·A_r·x_r,  e = the plain factor's residual at (P', l_s)
// (PosePointFactor2/3, BearingRangeFactor2). This equals the plain factor at the common-frame
// pose and point (A_r·x_r, A_s·l_s): the observation is frame-invariant.
// Keys, in order: A_r, x_r, A_s (pose type), l_s (point type). With right perturbations:
//   x_r·Exp(δ):  P'·Exp(δ)                  → ∂e/∂δx_r = ∂e/∂δP'
//   A_r·Exp(δ):  P'·Exp(Ad(x_r⁻¹)δ)         → ∂e/∂δA_r = ∂e/∂δP'·Ad(x_r⁻¹)
//   A_s·Exp(δ):  Exp(−δ)·A_s⁻¹·A_r·x_r = P'·Exp(−Ad(P'⁻¹)δ)
//                                           → ∂e/∂δA_s = −∂e/∂δP'·Ad(P'⁻¹)
//   l_s + δ:                                → ∂e/∂δl_s = the plain factor's point Jacobian.
#include "solvers/factors/landmark_factors.h"

namespace loopd::server {

/// A 2D sighting (Inner: PosePointFactor2, or BearingRangeFactor2 with measured = (bearing
/// rad, range m) and information over them) through the anchors.
template <class Inner>
class AnchoredSighting2 final : public Factor {
 public:
  AnchoredSighting2(Key anchorR, Key poseR, Key anchorS, Key landmarkS, const Vec2& measured,
                    const Eigen::Matrix2d& information, FactorRole role = FactorRole::Landmark);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override;
  const Vec2& measured() const { return inner_.measured(); }
  const Eigen::Matrix2d& information() const { return inner_.information(); }

 private:
  Inner inner_;  // evaluated on (P', l_s)
};

using AnchoredPosePointFactor2 = AnchoredSighting2<PosePointFactor2>;
using AnchoredBearingRangeFactor2 = AnchoredSighting2<BearingRangeFactor2>;
template <>
const char* AnchoredSighting2<PosePointFactor2>::typeName() const;
template <>
const char* AnchoredSighting2<BearingRangeFactor2>::typeName() const;
extern template class AnchoredSighting2<PosePointFactor2>;
extern template class AnchoredSighting2<BearingRangeFactor2>;

class AnchoredPosePointFactor3 final : public Factor {
 public:
  AnchoredPosePointFactor3(Key anchorR, Key poseR, Key anchorS, Key landmarkS, const Vec3& measured,
                           const Mat3& information, FactorRole role = FactorRole::Landmark);
  void evaluate(const double* const* x, double* r, double* const* J) const override;
  std::unique_ptr<Factor> clone() const override;
  const char* typeName() const override { return "AnchoredPosePoint3"; }
  const Vec3& measured() const { return inner_.measured(); }
  const Mat3& information() const { return inner_.information(); }

 private:
  PosePointFactor3 inner_;
};

}  // namespace loopd::server
