#pragma once
// Information (and covariance) matrices as files store them: an upper triangle in some order.
// Shared by the readers so every format gets the same checks: finite entries, symmetric by
// construction, positive definite by a Cholesky (LLT) of the dim×dim block. Internal.
#include <Eigen/Core>
#include <cstddef>

#include "solvers/io/line_scanner.h"

namespace loopd::io::detail {

using Information = Eigen::Matrix<double, 6, 6>;

/// Where one stored value goes: (row, col) in the upper triangle.
struct TriangleEntry {
  int row, col;
};

/// g2o's order: the upper triangle row by row, dim·(dim+1)/2 entries (dim ≤ 6).
const TriangleEntry* rowMajorUpper(int dim);

/// Reads the dim·(dim+1)/2 fields from `first` (after the tag, 0-based), placed by `order`,
/// as an information matrix; fails on the line unless it is positive definite.
Information readInformation(const LineScanner& in, std::size_t first, int dim,
                            const TriangleEntry* order);

/// As readInformation, but the fields are a covariance: checks it, returns its inverse.
Information readCovarianceAsInformation(const LineScanner& in, std::size_t first, int dim,
                                        const TriangleEntry* order);

}  // namespace loopd::io::detail
