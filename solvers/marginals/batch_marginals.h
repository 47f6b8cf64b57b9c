#pragma once
// Marginal covariances from a batch solution: factor H once at the estimate, then solve for
// the columns of the wanted keys (in chunks, so all poses of a large graph fit in memory).
#include <Eigen/Core>
#include <vector>

#include "solvers/batch/nonlinear_optimizer.h"

namespace loopd {

/// Joint marginal of keys at values (keys in the order given, each in its tangent space).
/// Fixed (gauge) variables have zero covariance. Throws std::runtime_error if H is singular.
Eigen::MatrixXd jointMarginal(NonlinearOptimizer& optimizer, const Values& values,
                              const std::vector<Key>& keys, const double* weights = nullptr);

/// Each key's own marginal (block diagonal of the joint), computed chunk by chunk.
std::vector<Eigen::MatrixXd> individualMarginals(NonlinearOptimizer& optimizer,
                                                 const Values& values,
                                                 const std::vector<Key>& keys,
                                                 const double* weights = nullptr);

}  // namespace loopd
