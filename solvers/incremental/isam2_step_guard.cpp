// The step guard (Isam2Options::guardSteps): iSAM2 takes each update's Gauss–Newton step
// whole. Under a max-mixture, a wrong closure taken as an inlier far from where it agrees
// can make that step raise the objective; the guard cuts such a step back along its path.
#include <algorithm>
#include <array>
#include <cstring>

#include "solvers/geometry/se2.h"
#include "solvers/geometry/se3.h"
#include "solvers/incremental/isam2.h"

namespace loopd {

namespace {

/// The point a fraction t along a path from a to b (storage of one variable of type type):
/// SE3 along the group's geodesic, SE2 by scaling the relative pose's (x, y, θ) in a's
/// frame, points and scalars on the straight line.
void along(VarType type, const double* a, const double* b, double t, double* out) {
  switch (type) {
    case VarType::SE2: {
      const SE2 A(a[0], a[1], a[2]);
      const SE2 d = A.between(SE2(b[0], b[1], b[2]));
      const SE2 x = A * SE2(t * d.x, t * d.y, t * d.theta);
      out[0] = x.x, out[1] = x.y, out[2] = x.theta;
      return;
    }
    case VarType::SE3: {
      const SE3 A(Eigen::Map<const Mat3>(a), Eigen::Map<const Vec3>(a + 9));
      const SE3 B(Eigen::Map<const Mat3>(b), Eigen::Map<const Vec3>(b + 9));
      const SE3 x = A * expSE3(t * logSE3(A.between(B)));
      Eigen::Map<Mat3> R(out);
      Eigen::Map<Vec3> p(out + 9);
      R = x.R;
      p = x.t;
      return;
    }
    default:
      for (int i = 0; i < varDim(type); ++i) out[i] = a[i] + t * (b[i] - a[i]);
  }
}

}  // namespace

void Isam2Backend::recordBeforeStep(int v) {
  if (guardStamp_[v] == epoch_) return;
  guardStamp_[v] = epoch_;
  guardIndex_[v] = static_cast<int>(guardVars_.size());
  guardVars_.push_back(v);
  const double* x = estimate_.data(v);
  guardBefore_.insert(guardBefore_.end(), x, x + kValueStride);
}

double Isam2Backend::guardedObjective(const std::vector<double>* stepped) const {
  double sum = 0.0;
  std::array<const double*, kMaxFactorKeys> x{};
  for (int f : guardFactors_) {
    const Factor& F = *factors_[f];
    for (int k = 0; k < F.size(); ++k) {
      const int v = factorVars_[f][k];
      x[k] = stepped && guardStamp_[v] == epoch_
                 ? &(*stepped)[static_cast<size_t>(guardIndex_[v]) * kValueStride]
                 : estimate_.data(v);
    }
    sum += F.objective(x.data());
  }
  return sum;
}

void Isam2Backend::guardStep() {
  stats_.stepKept = 1.0;
  if (guardVars_.empty()) return;
  guardFactors_.clear();
  for (int v : guardVars_)
    for (int f : varFactors_[v])
      if (guardFactorStamp_[f] != epoch_) {
        guardFactorStamp_[f] = epoch_;
        guardFactors_.push_back(f);
      }
  const double before = guardedObjective(&guardBefore_);
  const double taken = guardedObjective(nullptr);
  if (taken <= before * (1.0 + 1e-9) + 1e-12) return;

  // Halve along the path until the objective drops below where the step started. The
  // estimate still holds the whole step until the best point is written back.
  std::vector<double> trial(guardBefore_.size()), best;
  double bestCost = taken, t = 1.0;
  for (int i = 0; i < 10; ++i) {
    t *= 0.5;
    for (size_t j = 0; j < guardVars_.size(); ++j) {
      const int v = guardVars_[j];
      const size_t o = j * kValueStride;
      along(estimate_.type(v), &guardBefore_[o], estimate_.data(v), t, &trial[o]);
    }
    const double c = guardedObjective(&trial);
    if (c < bestCost) {
      bestCost = c;
      best = trial;
      stats_.stepKept = t;
    }
    if (c < before) break;
  }
  if (best.empty()) return;

  // Relinearize the stepped variables where the cut-back step leaves them: θ = estimate,
  // Δ = 0, their cliques (and those of their factors) re-eliminated. No back-substitution:
  // the new tree's step from there waits for later updates, as after resetEstimate().
  const long stepEpoch = epoch_++;
  affected_.clear();
  if (newestVar_ >= 0) constrainedStamp_[newestVar_] = epoch_;
  for (size_t j = 0; j < guardVars_.size(); ++j) {
    const int v = guardVars_[j];
    if (constrainedStamp_[v] == stepEpoch) constrainedStamp_[v] = epoch_;  // still ordered last
    std::memcpy(estimate_.data(v), &best[j * kValueStride], sizeof(double) * kValueStride);
    if (varFactors_[v].empty()) continue;
    relinearizeAtEstimate(v);
    markWithItsFactors(v);
  }
  recompute();
}

}  // namespace loopd
