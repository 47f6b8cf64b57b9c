#include "solvers/io/information.h"

#include <Eigen/Cholesky>
#include <array>
#include <string>

namespace loopd::io::detail {

namespace {

Information readSymmetric(const LineScanner& in, std::size_t first, int dim,
                          const TriangleEntry* order) {
  Information m = Information::Zero();
  const int n = dim * (dim + 1) / 2;
  for (int k = 0; k < n; ++k) {
    const double v = in.number(first + k);
    m(order[k].row, order[k].col) = v;
    m(order[k].col, order[k].row) = v;
  }
  return m;
}

// Fixed-size Cholesky per dimension: no heap allocation per edge.
template <int D>
bool factorAndMaybeInvert(Information& m, bool invert) {
  const Eigen::Matrix<double, D, D> block = m.template topLeftCorner<D, D>();
  const Eigen::LLT<Eigen::Matrix<double, D, D>> llt(block);
  if (llt.info() != Eigen::Success) return false;
  if (invert) {
    // Column by column: a vector right-hand side keeps Eigen on its small fixed-size path.
    Eigen::Matrix<double, D, D> inv;
    for (int i = 0; i < D; ++i) inv.col(i) = llt.solve(Eigen::Matrix<double, D, 1>::Unit(i));
    m.template topLeftCorner<D, D>() = 0.5 * (inv + inv.transpose());  // exactly symmetric
  }
  return true;
}

bool positiveDefinite(Information& m, int dim, bool invert) {
  switch (dim) {
    case 1:
      return factorAndMaybeInvert<1>(m, invert);
    case 2:
      return factorAndMaybeInvert<2>(m, invert);
    case 3:
      return factorAndMaybeInvert<3>(m, invert);
    case 4:
      return factorAndMaybeInvert<4>(m, invert);
    case 5:
      return factorAndMaybeInvert<5>(m, invert);
    case 6:
      return factorAndMaybeInvert<6>(m, invert);
  }
  return false;
}

}  // namespace

const TriangleEntry* rowMajorUpper(int dim) {
  static const auto tables = [] {
    std::array<std::array<TriangleEntry, 21>, 7> t{};
    for (int d = 1; d <= 6; ++d) {
      int k = 0;
      for (int i = 0; i < d; ++i) {
        for (int j = i; j < d; ++j) t[d][k++] = {i, j};
      }
    }
    return t;
  }();
  return tables.at(dim).data();
}

Information readInformation(const LineScanner& in, std::size_t first, int dim,
                            const TriangleEntry* order) {
  Information m = readSymmetric(in, first, dim, order);
  if (!positiveDefinite(m, dim, false)) {
    in.fail(std::string(in.tag()) + " information matrix is not positive definite");
  }
  return m;
}

Information readCovarianceAsInformation(const LineScanner& in, std::size_t first, int dim,
                                        const TriangleEntry* order) {
  Information m = readSymmetric(in, first, dim, order);
  if (!positiveDefinite(m, dim, true)) {
    in.fail(std::string(in.tag()) + " covariance matrix is not positive definite");
  }
  if (!m.allFinite()) {
    in.fail(std::string(in.tag()) + " covariance matrix is too close to singular to invert");
  }
  return m;
}

}  // namespace loopd::io::detail
