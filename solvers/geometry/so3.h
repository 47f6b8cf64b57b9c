#pragma once
// SO(3) helpers on plain 3x3 rotation matrices: hat, Exp/Log and their Jacobians.
// Conventions: right perturbation R·Exp(ω); Jr is the right Jacobian of Exp.
#include <Eigen/Core>

namespace loopd {

using Mat3 = Eigen::Matrix3d;
using Vec3 = Eigen::Vector3d;

/// [ω]×, the skew-symmetric matrix with hat(a)·b = a × b.
Mat3 hat(const Vec3& w);

/// Rodrigues: Exp(ω) = I + sinθ/θ [ω]× + (1−cosθ)/θ² [ω]×².
Mat3 expSO3(const Vec3& w);

/// Log(R) with θ ∈ [0, π], stable near 0 and near π.
Vec3 logSO3(const Mat3& R);

/// Right Jacobian Jr(ω) of Exp: Exp(ω+δ) ≈ Exp(ω)·Exp(Jr(ω)δ).
Mat3 rightJacobianSO3(const Vec3& w);

/// Inverse of the right Jacobian: Log(Exp(ω)·Exp(δ)) ≈ ω + Jr⁻¹(ω)δ.
Mat3 rightJacobianInverseSO3(const Vec3& w);

/// Nearest rotation (Frobenius norm) to an arbitrary 3x3 matrix, via SVD.
Mat3 projectToSO3(const Mat3& M);

}  // namespace loopd
