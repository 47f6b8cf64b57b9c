#include "solvers/marginals/batch_marginals.h"

#include <stdexcept>

namespace loopd {

namespace {

struct KeyColumns {
  std::vector<int> offset;  // scalar offset in H, −1 if fixed
  std::vector<int> dim;
  std::vector<int> start;   // first row/column in the joint matrix
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
  if (!opt.factorizeAt(values, weights))
    throw std::runtime_error("marginals: information matrix is singular at the estimate");
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

}  // namespace

Eigen::MatrixXd jointMarginal(NonlinearOptimizer& opt, const Values& values,
                              const std::vector<Key>& keys, const double* weights) {
  const KeyColumns kc = locate(opt, values, keys);
  factorOrThrow(opt, values, weights);
  Eigen::MatrixXd joint = Eigen::MatrixXd::Zero(kc.total, kc.total);
  if (opt.layout().dimension() == 0 || kc.total == 0) return joint;
  const Eigen::MatrixXd X = solveColumns(opt, kc, 0, keys.size(), kc.total);
  for (size_t r = 0; r < keys.size(); ++r) {
    if (kc.offset[r] < 0) continue;
    joint.middleRows(kc.start[r], kc.dim[r]) = X.middleRows(kc.offset[r], kc.dim[r]);
  }
  for (size_t c = 0; c < keys.size(); ++c)
    if (kc.offset[c] < 0) joint.middleCols(kc.start[c], kc.dim[c]).setZero();
  return joint;
}

std::vector<Eigen::MatrixXd> individualMarginals(NonlinearOptimizer& opt, const Values& values,
                                                 const std::vector<Key>& keys,
                                                 const double* weights) {
  const KeyColumns kc = locate(opt, values, keys);
  factorOrThrow(opt, values, weights);
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
