// Far-out closures out of the inner iSAM2 (RisamOptions::parkFactor): when to park one, and
// its χ² predicted with the map's own uncertainty, rᵀ(I + JΣJᵀ)⁻¹r, which also drives the
// retry of rejected closures at optimize().
#include "robust/risam_backend.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <array>
#include <limits>

namespace loopd {

void RisamBackend::park(FactorId id) {
  Graduated& g = graduated_[id];
  g.parked = true;
  g.decided = false;
  parked_.push_back(id);
}

void RisamBackend::unpark(FactorId id) {
  graduated_[id].parked = false;
  parked_.erase(std::find(parked_.begin(), parked_.end(), id));
}

bool RisamBackend::farOut(const Graduated& g, const Values& x) const {
  if (!(options_.parkFactor > 0.0) || g.parked || g.decided) return false;
  return g.original->chi2(x) > options_.parkFactor * tailChi2(g.original->dim());
}

void RisamBackend::markFarOut(const std::vector<FactorId>& ids) {
  const Values& x = inner_->estimate();
  for (FactorId id : ids)
    if (farOut(graduated_[id], x)) toPark_.push_back(id);
}

bool RisamBackend::shouldPark(FactorId id) {
  auto it = graduated_.find(id);
  if (it == graduated_.end() || !farOut(it->second, inner_->estimate())) return false;
  // Only where the map is sure: on a flexible map (parking-garage) true closures sit at χ² in
  // the thousands while wrong ones bend it, but within a few tail gates of the map's own
  // uncertainty; left in, their small weights pull the map back as it straightens.
  const Factor& f = *it->second.original;
  return predictedChi2(f) > options_.parkPredictedFactor * tailChi2(f.dim());
}

double RisamBackend::predictedChi2(const Factor& f) {
  // rᵀ(I + J Σ Jᵀ)⁻¹r: the whitened residual against its covariance when the map may still
  // move by its marginal covariance Σ (joint over the factor's variables).
  const Values& x = inner_->estimate();
  std::vector<Key> keys;
  std::array<const double*, kMaxFactorKeys> xp{};
  std::array<JacobianBlock, kMaxFactorKeys> jb{};
  std::array<double*, kMaxFactorKeys> jp{};
  int cols = 0;
  for (int i = 0; i < f.size(); ++i) {
    const int s = x.slot(f.key(i));
    if (s < 0) return std::numeric_limits<double>::infinity();
    xp[i] = x.data(s);
    jp[i] = jb[i].data();
    keys.push_back(f.key(i));
    cols += varDim(f.varType(i));
  }
  const int d = f.dim();
  Eigen::VectorXd r(d);
  f.evaluate(xp.data(), r.data(), jp.data());
  Eigen::MatrixXd J(d, cols);
  for (int i = 0, c = 0; i < f.size(); c += varDim(f.varType(i)), ++i)
    J.middleCols(c, varDim(f.varType(i))) =
        Eigen::Map<const Eigen::MatrixXd>(jb[i].data(), d, varDim(f.varType(i)));
  const Eigen::MatrixXd sigma = inner_->marginalCovariance(keys);
  if (sigma.rows() != cols || sigma.cols() != cols) return std::numeric_limits<double>::infinity();
  const Eigen::MatrixXd S = Eigen::MatrixXd::Identity(d, d) + J * sigma * J.transpose();
  Eigen::LDLT<Eigen::MatrixXd> ldlt(S);
  if (ldlt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  return r.dot(ldlt.solve(r));
}

}  // namespace loopd
