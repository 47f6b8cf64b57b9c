// Residuals of the reference protocol (../shared/REFERENCE.md, issue 2 "Foundation"):
//   Δ = Z⁻¹·Xi⁻¹·Xj
//   SE(2): r = (x, y, wrapped θ) of Δ
//   SE(3): r = Log_SE3(Δ) = (ρ, φ), translation first, φ = Log(R), ρ = V(φ)⁻¹·t
// whitened by W with WᵀW = Ω, so rᵀΩr = |W·r|². Templated for ceres::AutoDiffCostFunction and
// reused with T = double to compute chi2.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cmath>

namespace ceres_baseline {

constexpr double kPi = 3.14159265358979323846;

// Wrap to [-π, π). floor() of a ceres::Jet carries no derivative, so d/da = 1 as wanted.
template <typename T>
T wrap_angle(const T& a) {
  using std::floor;
  return a - T(2.0 * kPi) * floor((a + T(kPi)) / T(2.0 * kPi));
}

// φ = Log(q) for a unit quaternion (rotation vector, |φ| ≤ π). Smooth at φ = 0: Taylor branch
// of atan(x)/x for x = |v|/w small (no sqrt of a vanishing quantity under autodiff).
template <typename T>
Eigen::Matrix<T, 3, 1> log_so3(const Eigen::Quaternion<T>& q_in) {
  using std::atan2;
  using std::sqrt;
  Eigen::Quaternion<T> q = q_in;
  if (q.w() < T(0)) q.coeffs() = -q.coeffs();  // shortest rotation, w ≥ 0
  const Eigen::Matrix<T, 3, 1> v = q.vec();
  const T n2 = v.squaredNorm();
  const T w = q.w();
  if (n2 < T(1e-4) * w * w) {
    // θ = 2·atan(n/w); φ = v·θ/n = v·(2/w)·(1 − s/3 + s²/5 − s³/7), s = n²/w²  (error ~ s⁴/9)
    const T s = n2 / (w * w);
    const T f =
        (T(2.0) / w) * (T(1.0) - s * (T(1.0 / 3.0) - s * (T(1.0 / 5.0) - s * T(1.0 / 7.0))));
    return v * f;
  }
  const T n = sqrt(n2);
  const T theta = T(2.0) * atan2(n, w);
  return v * (theta / n);
}

// ρ = V(φ)⁻¹·t with V⁻¹ = I − ½[φ]× + c(θ)·[φ]×², c = (1 − (θ/2)·cot(θ/2)) / θ².
template <typename T>
Eigen::Matrix<T, 3, 1> inv_left_jacobian_times(const Eigen::Matrix<T, 3, 1>& phi,
                                               const Eigen::Matrix<T, 3, 1>& t) {
  using std::cos;
  using std::sin;
  using std::sqrt;
  const T th2 = phi.squaredNorm();
  T c;
  if (th2 < T(1e-2)) {
    // 1/12 + θ²/720 + θ⁴/30240 + θ⁶/1209600 (next term θ⁸/47900160 < 3e-19 here)
    c = T(1.0 / 12.0) +
        th2 * (T(1.0 / 720.0) + th2 * (T(1.0 / 30240.0) + th2 * T(1.0 / 1209600.0)));
  } else {
    const T th = sqrt(th2);
    const T h = T(0.5) * th;
    c = (T(1.0) - h * cos(h) / sin(h)) / th2;
  }
  const Eigen::Matrix<T, 3, 1> pt = phi.cross(t);
  return t - T(0.5) * pt + c * phi.cross(pt);
}

struct Se2Residual {
  double zx, zy, zth;
  Eigen::Matrix3d W;

  template <typename T>
  bool operator()(const T* pi, const T* thi, const T* pj, const T* thj, T* out) const {
    using std::cos;
    using std::sin;
    // A = Xi⁻¹·Xj
    const T ci = cos(thi[0]), si = sin(thi[0]);
    const T dx = pj[0] - pi[0], dy = pj[1] - pi[1];
    const T ax = ci * dx + si * dy;
    const T ay = -si * dx + ci * dy;
    const T ath = thj[0] - thi[0];
    // Δ = Z⁻¹·A = (R(zθ)ᵀ(tA − tZ), θA − zθ)
    const double cz = std::cos(zth), sz = std::sin(zth);
    const T ex = ax - T(zx), ey = ay - T(zy);
    Eigen::Matrix<T, 3, 1> r;
    r(0) = T(cz) * ex + T(sz) * ey;
    r(1) = T(-sz) * ex + T(cz) * ey;
    r(2) = wrap_angle(ath - T(zth));
    Eigen::Map<Eigen::Matrix<T, 3, 1>> res(out);
    res = W.template cast<T>().template triangularView<Eigen::Upper>() * r;  // W is upper
    return true;
  }
};

struct Se3Residual {
  Eigen::Vector3d zt;
  Eigen::Quaterniond zq;  // unit
  Eigen::Matrix<double, 6, 6> W;

  // t: 3 translation, q: 4 quaternion (Eigen order x, y, z, w)
  template <typename T>
  bool operator()(const T* ti, const T* qi, const T* tj, const T* qj, T* out) const {
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> Ti(ti), Tj(tj);
    const Eigen::Map<const Eigen::Quaternion<T>> Qi(qi), Qj(qj);
    // A = Xi⁻¹·Xj
    const Eigen::Quaternion<T> Qi_inv = Qi.conjugate();
    const Eigen::Matrix<T, 3, 1> tA = Qi_inv * (Tj - Ti);
    const Eigen::Quaternion<T> qA = Qi_inv * Qj;
    // Δ = Z⁻¹·A
    const Eigen::Quaternion<T> qZinv = zq.conjugate().template cast<T>();
    const Eigen::Matrix<T, 3, 1> tD = qZinv * (tA - zt.template cast<T>());
    const Eigen::Quaternion<T> qD = qZinv * qA;
    // r = Log_SE3(Δ) = (ρ, φ)
    Eigen::Matrix<T, 6, 1> r;
    const Eigen::Matrix<T, 3, 1> phi = log_so3(qD);
    r.template head<3>() = inv_left_jacobian_times(phi, tD);
    r.template tail<3>() = phi;
    Eigen::Map<Eigen::Matrix<T, 6, 1>> res(out);
    res = W.template cast<T>().template triangularView<Eigen::Upper>() * r;  // W is upper
    return true;
  }
};

}  // namespace ceres_baseline
