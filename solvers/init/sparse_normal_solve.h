#pragma once
// The one sparse solve the linear initialisations share: normal equations given as triplets
// (both triangles, duplicates summed) solved by CHOLMOD with a fill-reducing order.
#include <Eigen/Core>
#include <Eigen/SparseCore>

#include <vector>

namespace loopd {

using InitTriplets = std::vector<Eigen::Triplet<double>>;

/// x = H⁻¹·rhs for the n×n symmetric H assembled from triplets. Throws std::runtime_error if
/// H is not (numerically) positive definite.
Eigen::MatrixXd solveNormalEquations(int n, const InitTriplets& triplets,
                                     const Eigen::MatrixXd& rhs);

}  // namespace loopd
