#include "solvers/marginals/batch_marginals.h"

#include <stdexcept>

#include "solvers/marginals/singular_information.h"

namespace loopd {

namespace {

struct KeyColumns {
  std::vector<int> offset;  // scalar offset in H, −1 if fixed
  std::vector<int> dim;
  std::vector<int> start;  // first row/column in the joint matrix
  int total = 0;
};

KeyColumns locate(const NonlinearOptimizer& opt, const Values& values,
                  const std::vector<Key>& keys) {
  KeyColumns kc;
  for (Key k : keys) {
    const int s = values.slot(k);
    if (s < 0) throw std::invalid_argument("no variable " + keyToString(k));
    kc.offset.push_back(opt.layout().slotOffset()[s]);
    kc.dim.push_back(varDim(values.type(s)));
    kc.start.push_back(kc.total);
    kc.total += kc.dim.back();
  }
  return kc;
}

void factorOrThrow(NonlinearOptimizer& opt, const Values& values, const double* weights) {
  if (!opt.factorizeAt(values, weights)) throw std::runtime_error(kSingularInformationMessage);
}

// Solves H·X = E for the unit columns of keys [first, last) and returns X (n × cols).
Eigen::MatrixXd solveColumns(NonlinearOptimizer& opt, const KeyColumns& kc, size_t first,
                             size_t last, int cols) {
  const int n = opt.layout().dimension();
  Eigen::MatrixXd E = Eigen::MatrixXd::Zero(n, cols), X(n, cols);
  int c = 0;
  for (size_t i = first; i < last; ++i)
    for (int d = 0; d < kc.dim[i]; ++d, ++c)
      if (kc.offset[i] >= 0) E(kc.offset[i] + d, c) = 1.0;
  opt.cholesky().solve(E.data(), X.data(), cols);
  return X;
}

// The joint marginal of located keys on the current factorization.
Eigen::MatrixXd jointBlock(NonlinearOptimizer& opt, const KeyColumns& kc) {
  Eigen::MatrixXd joint = Eigen::MatrixXd::Zero(kc.total, kc.total);
  std::vector<int> scalars, at;  // free scalars and their rows in joint
  for (size_t i = 0; i < kc.offset.size(); ++i)
    if (kc.offset[i] >= 0)
      for (int d = 0; d < kc.dim[i]; ++d) {
        scalars.push_back(kc.offset[i] + d);
        at.push_back(kc.start[i] + d);
      }
  if (scalars.empty()) return joint;
  const int m = static_cast<int>(scalars.size());
  Eigen::MatrixXd inv(m, m);
  opt.cholesky().inverseBlock(scalars, inv.data());
  for (int a = 0; a < m; ++a)
    for (int b = 0; b < m; ++b) joint(at[a], at[b]) = inv(a, b);
  return joint;
}

}  // namespace

Eigen::MatrixXd jointMarginal(NonlinearOptimizer& opt, const Values& values,
                              const std::vector<Key>& keys, const double* weights) {
  return jointMarginals(opt, values, {keys}, weights).front();
}

std::vector<Eigen::MatrixXd> jointMarginals(NonlinearOptimizer& opt, const Values& values,
                                            const std::vector<std::vector<Key>>& keySets,
                                            const double* weights,
                                            const std::function<void()>& beforeEachSet) {
  // Factorize first: the layout (and so the offsets) follows the weights (fitPattern).
  factorOrThrow(opt, values, weights);
  std::vector<KeyColumns> located;
  for (const auto& keys : keySets) located.push_back(locate(opt, values, keys));
  std::vector<Eigen::MatrixXd> out;
  for (const KeyColumns& kc : located) {
    if (beforeEachSet) beforeEachSet();
    out.push_back(jointBlock(opt, kc));
  }
  return out;
}

std::vector<Eigen::MatrixXd> individualMarginals(NonlinearOptimizer& opt, const Values& values,
                                                 const std::vector<Key>& keys,
                                                 const double* weights) {
  factorOrThrow(opt, values, weights);
  const KeyColumns kc = locate(opt, values, keys);
  std::vector<Eigen::MatrixXd> out(keys.size());
  constexpr size_t kChunkKeys = 64;
  for (size_t first = 0; first < keys.size(); first += kChunkKeys) {
    const size_t last = std::min(keys.size(), first + kChunkKeys);
    const int cols = kc.start[last - 1] + kc.dim[last - 1] - kc.start[first];
    const Eigen::MatrixXd X = solveColumns(opt, kc, first, last, cols);
    for (size_t i = first; i < last; ++i) {
      out[i] = Eigen::MatrixXd::Zero(kc.dim[i], kc.dim[i]);
      if (kc.offset[i] >= 0)
        out[i] = X.block(kc.offset[i], kc.start[i] - kc.start[first], kc.dim[i], kc.dim[i]);
    }
  }
  return out;
}

}  // namespace loopd
