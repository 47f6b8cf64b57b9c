#pragma once
// What adding or removing groups of factors would do to a solved least-squares problem, from
// the joint marginal Σ of their variables and their whitened residuals r and Jacobians J at
// the estimate, without re-solving (the rank-k update / downdate of the normal equations,
// exact for a linear problem):
//   adding a group (Σ without it) raises the optimal cost by   rᵀ(I + JΣJᵀ)⁻¹r
//   removing a group (Σ with it) lowers the optimal cost by    rᵀ(I − JΣJᵀ)⁻¹r
// GNC uses both: rejected closures that would fit the map's own uncertainty come back, and
// clusters of accepted closures that hold the map bent go.
#include <Eigen/Core>
#include <functional>
#include <vector>

#include "solvers/core/values.h"
#include "solvers/graph/factor_graph.h"

namespace loopd {

/// The joint marginal covariance of each key set (keys in their order), as
/// BatchBackend::jointMarginals.
using JointMarginalsFn =
    std::function<std::vector<Eigen::MatrixXd>(const std::vector<std::vector<Key>>&)>;

enum class GroupChange { Add, Remove };

/// For each group (factor indices into graph): the predicted cost rise on adding it (Add) or
/// cost drop on removing it (Remove), both ≥ 0; NaN where it cannot be told (a variable
/// missing from values, marginals failing with a runtime_error or logic_error, a singular
/// system). Other exceptions from marginals (a caller giving up) pass.
std::vector<double> predictedCostChange(const FactorGraph& graph, const Values& values,
                                        const std::vector<std::vector<int>>& groups,
                                        GroupChange change, const JointMarginalsFn& marginals);

/// Clusters of the given factors: two-variable factors (and inter-robot ones through anchors,
/// (A_r, x_r, A_s, y_s), by x_r and y_s) whose ends, as variable slots of values (ordered low
/// to high end), are both within `window` slots of another member's (a run of closures
/// between the same two stretches of trajectory, or a group of wrong ones). Other factors are
/// clusters of their own.
std::vector<std::vector<int>> closureClusters(const FactorGraph& graph, const Values& values,
                                              const std::vector<int>& factors, int window);

}  // namespace loopd
