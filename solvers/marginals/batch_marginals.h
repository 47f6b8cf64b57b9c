#pragma once
// Marginal covariances from a batch solution: factor H once at the estimate, then read the
// joint blocks of the wanted keys off the factor (jointMarginal(s)) or solve for their columns
// in chunks (individualMarginals, so all poses of a large graph fit in memory).
#include <Eigen/Core>
#include <functional>
#include <vector>

#include "solvers/batch/nonlinear_optimizer.h"

namespace loopd {

/// Joint marginal of keys at values (keys in the order given, each in its tangent space).
/// Fixed (gauge) variables have zero covariance. Throws std::runtime_error if H is singular.
Eigen::MatrixXd jointMarginal(NonlinearOptimizer& optimizer, const Values& values,
                              const std::vector<Key>& keys, const double* weights = nullptr);

/// The joint marginal of each key set, all on one factorization at values (each set's entries
/// read off the factor along its variables' elimination-tree paths: cheap for small sets).
/// beforeEachSet, if set, is called before each set's block: a caller that must be able to
/// give up (a look that yields to input) throws from it.
std::vector<Eigen::MatrixXd> jointMarginals(NonlinearOptimizer& optimizer, const Values& values,
                                            const std::vector<std::vector<Key>>& keySets,
                                            const double* weights = nullptr,
                                            const std::function<void()>& beforeEachSet = {});

/// Each key's own marginal (block diagonal of the joint), computed chunk by chunk.
std::vector<Eigen::MatrixXd> individualMarginals(NonlinearOptimizer& optimizer,
                                                 const Values& values, const std::vector<Key>& keys,
                                                 const double* weights = nullptr);

}  // namespace loopd
