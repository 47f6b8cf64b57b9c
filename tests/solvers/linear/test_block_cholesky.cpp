// BlockCholesky (solves and entries of the inverse) against a dense Eigen LLT on random
// block-sparse SPD matrices (mixed block sizes 1..6, orders with and without postorder
// changes, narrow and wide supernodes), and against SparseCholesky (CHOLMOD) on real
// pose-graph Hessians.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Dense>
#include <cmath>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "solvers/io/dataset_reader.h"
#include "solvers/linear/block_cholesky.h"
#include "solvers/linear/hessian_layout.h"
#include "solvers/linear/normal_equations.h"
#include "solvers/linear/sparse_cholesky.h"
#include "solvers/problem/pose_graph_problem.h"

namespace loopd {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;

// A block-structured symmetric matrix in HessianLayout's CSC convention plus its dense copy.
struct BlockMatrix {
  std::vector<int> blockOffsets, columnStart, rowIndex;
  std::vector<double> values;
  MatrixXd dense;
};

// Random block pattern: a chain plus random extra couplings with probability density, sizes
// drawn from `sizes`. The matrix is SPD by diagonal dominance; the strictly lower part of each
// stored diagonal block holds garbage that must be ignored.
// probability(i, j), i < j: the chance that blocks i and j are coupled.
BlockMatrix randomBlockMatrix(unsigned seed, int nb, const std::vector<int>& sizes,
                              const std::function<double(int, int)>& probability) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::uniform_int_distribution<int> pick(0, static_cast<int>(sizes.size()) - 1);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  BlockMatrix m;
  m.blockOffsets.push_back(0);
  for (int b = 0; b < nb; ++b) m.blockOffsets.push_back(m.blockOffsets.back() + sizes[pick(rng)]);
  const int n = m.blockOffsets.back();
  std::vector<std::vector<char>> link(nb, std::vector<char>(nb, 0));
  for (int j = 0; j < nb; ++j)
    for (int i = 0; i < j; ++i) link[i][j] = unit(rng) < probability(i, j);
  m.dense = MatrixXd::Zero(n, n);
  auto range = [&](int b) {
    return std::make_pair(m.blockOffsets[b], m.blockOffsets[b + 1] - m.blockOffsets[b]);
  };
  for (int j = 0; j < nb; ++j)
    for (int i = 0; i < j; ++i)
      if (link[i][j]) {
        const auto [oi, di] = range(i);
        const auto [oj, dj] = range(j);
        for (int r = 0; r < di; ++r)
          for (int c = 0; c < dj; ++c) m.dense(oi + r, oj + c) = m.dense(oj + c, oi + r) = u(rng);
      }
  for (int j = 0; j < nb; ++j) {
    const auto [o, d] = range(j);
    for (int r = 0; r < d; ++r)
      for (int c = r + 1; c < d; ++c) m.dense(o + r, o + c) = m.dense(o + c, o + r) = 0.3 * u(rng);
  }
  for (int k = 0; k < n; ++k)
    m.dense(k, k) = m.dense.row(k).cwiseAbs().sum() + 0.5 + std::abs(u(rng));

  m.columnStart.push_back(0);
  for (int j = 0; j < nb; ++j) {
    const auto [oj, dj] = range(j);
    for (int c = 0; c < dj; ++c) {
      for (int i = 0; i <= j; ++i) {
        if (i < j && !link[i][j]) continue;
        const auto [oi, di] = range(i);
        for (int r = 0; r < di; ++r) {
          m.rowIndex.push_back(oi + r);
          const bool lowerOfDiagonal = i == j && r > c;
          m.values.push_back(lowerOfDiagonal ? 1e3 * u(rng) : m.dense(oi + r, oj + c));
        }
      }
      m.columnStart.push_back(static_cast<int>(m.rowIndex.size()));
    }
  }
  return m;
}

BlockMatrix randomBlockMatrix(unsigned seed, int nb, const std::vector<int>& sizes, double density,
                              bool chain = true) {
  return randomBlockMatrix(seed, nb, sizes,
                           [&](int i, int j) { return chain && i + 1 == j ? 1.0 : density; });
}

double relativeError(const MatrixXd& x, const MatrixXd& ref) {
  return (x - ref).norm() / std::max(1.0, ref.norm());
}

void expectMatchesDense(const BlockMatrix& m) {
  const int n = m.blockOffsets.back();
  const Eigen::LLT<MatrixXd> llt(m.dense);
  ASSERT_EQ(llt.info(), Eigen::Success);
  BlockCholesky chol;
  EXPECT_FALSE(chol.analyzed());
  chol.analyze(m.blockOffsets, m.columnStart, m.rowIndex);
  EXPECT_TRUE(chol.analyzed());
  EXPECT_EQ(chol.dimension(), n);
  EXPECT_GE(chol.factorNonZeros(), n);
  EXPECT_GT(chol.flops(), 0.0);
  ASSERT_TRUE(chol.factorize(m.values));

  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  MatrixXd B(n, 4);
  for (int i = 0; i < B.size(); ++i) B.data()[i] = u(rng);
  const MatrixXd ref = llt.solve(B);

  VectorXd x(n);
  chol.solve(B.data(), x.data());
  EXPECT_LT(relativeError(x, ref.col(0)), 1e-10);

  MatrixXd X(n, 4);
  chol.solve(B.data(), X.data(), 4);
  EXPECT_LT(relativeError(X, ref), 1e-10);

  MatrixXd inPlace = B;  // x may alias b
  chol.solve(inPlace.data(), inPlace.data(), 4);
  EXPECT_LT(relativeError(inPlace, ref), 1e-10);

  // Entries of H⁻¹ at chosen scalars (any order), twice: the workspace must come back clean.
  const MatrixXd inverse = llt.solve(MatrixXd::Identity(n, n));
  for (int pick = 0; pick < 2; ++pick) {
    std::vector<int> scalars;
    for (int k = n - 1 - pick; k >= 0; k -= 1 + pick * 2 + k % 3) scalars.push_back(k);
    const int ms = static_cast<int>(scalars.size());
    MatrixXd got(ms, ms), want(ms, ms);
    chol.inverseBlock(scalars, got.data());
    for (int a = 0; a < ms; ++a)
      for (int b = 0; b < ms; ++b) want(a, b) = inverse(scalars[a], scalars[b]);
    EXPECT_LT(relativeError(got, want), 1e-10) << "pick " << pick;
  }

  // Refactorization on the same analysis with different values.
  BlockMatrix scaled = m;
  for (double& v : scaled.values) v *= 2.0;
  ASSERT_TRUE(chol.factorize(scaled.values));
  chol.solve(B.data(), X.data(), 4);
  EXPECT_LT(relativeError(X, 0.5 * ref), 1e-10);
}

TEST(BlockCholesky, RandomMixedBlockSizesMatchDenseLLT) {
  const std::vector<std::vector<int>> sizeSets = {
      {1, 2, 3, 4, 5, 6}, {3}, {6}, {2, 3}, {3, 6}, {1}};
  unsigned seed = 1;
  for (const auto& sizes : sizeSets)
    for (int nb : {1, 2, 5, 17, 40})
      for (double density : {0.0, 0.05, 0.2, 0.6}) {
        SCOPED_TRACE(::testing::Message()
                     << "seed " << seed << " nb " << nb << " density " << density << " sizes "
                     << sizes.size() << "/" << sizes.front());
        expectMatchesDense(randomBlockMatrix(seed++, nb, sizes, density));
      }
}

TEST(BlockCholesky, ForestAndDenseMatrices) {
  // No chain: a forest of independent pieces (several etree roots).
  expectMatchesDense(randomBlockMatrix(101, 30, {3, 6}, 0.03, false));
  expectMatchesDense(randomBlockMatrix(102, 12, {2, 3}, 0.0, false));  // block diagonal
  // Fully dense: one wide supernode (blocked dense kernels).
  expectMatchesDense(randomBlockMatrix(103, 30, {6}, 1.0));
  expectMatchesDense(randomBlockMatrix(104, 60, {1, 2, 3, 4, 5, 6}, 1.0));
  // Heavy fill: supernodes wider and taller than the 128-wide kernel tiles, updating their
  // ancestors both in place and through the scatter workspace.
  expectMatchesDense(randomBlockMatrix(105, 150, {6}, 0.04));
  expectMatchesDense(randomBlockMatrix(106, 200, {2, 3, 6}, 0.03));
  // A dense cluster of 30 blocks (one supernode of ~180 columns, deeper than a kernel tile)
  // coupled at random to 15 loosely coupled later blocks: its updates of them go through the
  // scatter workspace.
  for (unsigned seed : {107u, 108u})
    expectMatchesDense(randomBlockMatrix(seed, 45, {6, 5, 6}, [](int i, int j) {
      if (j < 30) return 1.0;
      if (i < 30) return i == 0 ? 0.6 : 0.0;  // through block 0 only: one fundamental supernode
      return 0.15;
    }));
}

TEST(BlockCholesky, NotPositiveDefiniteIsReported) {
  for (int nb : {1, 6, 40}) {
    BlockMatrix m = randomBlockMatrix(200 + nb, nb, {2, 3, 6}, 0.2);
    BlockCholesky chol;
    chol.analyze(m.blockOffsets, m.columnStart, m.rowIndex);
    ASSERT_TRUE(chol.factorize(m.values));
    // Make the last diagonal entry very negative: indefinite.
    std::vector<double> bad = m.values;
    bad.back() = -1e3;
    EXPECT_FALSE(chol.factorize(bad));
    EXPECT_FALSE(chol.factorized());
    EXPECT_THROW(chol.solve(bad.data(), bad.data()), std::logic_error);
    // Negative first pivot.
    bad = m.values;
    bad[0] = -1.0;
    EXPECT_FALSE(chol.factorize(bad));
    // Not a number.
    bad = m.values;
    bad[bad.size() / 2] = std::numeric_limits<double>::quiet_NaN();
    EXPECT_FALSE(chol.factorize(bad));
    // Zero matrix: zero pivot.
    EXPECT_FALSE(chol.factorize(std::vector<double>(m.values.size(), 0.0)));
    // And it recovers.
    ASSERT_TRUE(chol.factorize(m.values));
  }
}

TEST(BlockCholesky, RejectsInconsistentInput) {
  const BlockMatrix m = randomBlockMatrix(300, 5, {3}, 0.3);
  BlockCholesky chol;
  EXPECT_THROW(chol.factorize(m.values), std::logic_error);
  std::vector<int> shortStart(m.columnStart.begin(), m.columnStart.end() - 1);
  EXPECT_THROW(chol.analyze(m.blockOffsets, shortStart, m.rowIndex), std::invalid_argument);
  std::vector<int> badRows = m.rowIndex;
  badRows[0] = m.blockOffsets.back();
  EXPECT_THROW(chol.analyze(m.blockOffsets, m.columnStart, badRows), std::invalid_argument);
  chol.analyze(m.blockOffsets, m.columnStart, m.rowIndex);
  EXPECT_THROW(chol.factorize(std::vector<double>(3, 1.0)), std::invalid_argument);
}

// The real Gauss–Newton Hessian of a dataset at its initial values, first pose fixed.
struct DatasetCase {
  const char* file;
  // Forward comparison with CHOLMOD to 1e-9 relative. parking-garage's Hessian at the initial
  // values has a condition number near 1e15 (|x| ~ 1e8 for |b| ~ 1), so there both solvers are
  // only compared by backward error ‖Hx − b‖ / ‖b‖.
  bool wellConditioned;
};

class DatasetHessian : public ::testing::TestWithParam<DatasetCase> {};

// y = H x for H given by its upper-triangle CSC (diagonal blocks stored whole, lower half
// ignored).
VectorXd multiply(const HessianLayout& layout, const std::vector<double>& values,
                  const VectorXd& x) {
  const auto& cs = layout.columnStart();
  const auto& ri = layout.rowIndex();
  VectorXd y = VectorXd::Zero(x.size());
  for (int c = 0; c < layout.dimension(); ++c)
    for (int k = cs[c]; k < cs[c + 1]; ++k) {
      const int r = ri[k];
      if (r < c) {
        y[r] += values[k] * x[c];
        y[c] += values[k] * x[r];
      } else if (r == c) {
        y[r] += values[k] * x[c];
      }
    }
  return y;
}

TEST_P(DatasetHessian, MatchesCholmod) {
  const std::string path = std::string(LOOPD_DATASETS_DIR) + "/" + GetParam().file;
  const PoseGraphProblem problem = buildProblem(io::readDataset(path));
  std::vector<char> fixed(problem.initial.size(), 0);
  fixed[problem.initial.slot(problem.firstPose)] = 1;
  const HessianLayout layout(problem.graph, problem.initial, fixed);
  NormalEquations ne(layout);
  ne.build(problem.graph, problem.initial);
  const int n = layout.dimension();

  SparseCholesky cholmod(FactorizationKind::Auto);
  cholmod.analyze(n, layout.columnStart(), layout.rowIndex());
  ASSERT_TRUE(cholmod.factorize(ne.hessian()));
  BlockCholesky block;
  block.analyze(layout.blockOffsets(), layout.columnStart(), layout.rowIndex());
  ASSERT_TRUE(block.factorize(ne.hessian()));
  // Same elimination order (up to postordering), same structural factor.
  EXPECT_EQ(block.factorNonZeros(), cholmod.factorNonZeros());

  MatrixXd B(n, 3);
  B.col(0) = Eigen::Map<const VectorXd>(ne.gradient().data(), n);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = n; i < B.size(); ++i) B.data()[i] = u(rng);
  MatrixXd ref(n, 3), X(n, 3);
  cholmod.solve(B.data(), ref.data(), 3);
  block.solve(B.data(), X.data(), 3);
  for (int c = 0; c < 3; ++c) {
    SCOPED_TRACE(::testing::Message() << "column " << c);
    const double bnorm = B.col(c).norm();
    const double resCholmod =
        (multiply(layout, ne.hessian(), ref.col(c)) - B.col(c)).norm() / bnorm;
    const double resBlock = (multiply(layout, ne.hessian(), X.col(c)) - B.col(c)).norm() / bnorm;
    EXPECT_LT(resBlock, std::max(4.0 * resCholmod, 1e-13));
    if (GetParam().wellConditioned) {
      EXPECT_LT((X.col(c) - ref.col(c)).norm(), 1e-9 * ref.col(c).norm());
    }
  }

  VectorXd x(n);
  block.solve(B.data(), x.data());
  EXPECT_LT((x - X.col(0)).norm(), 1e-14 * X.col(0).norm());  // one column = the same arithmetic

  // A few entries of H⁻¹ (a closure's two ends and a far pose) against CHOLMOD's unit solves.
  const std::vector<int> scalars = {0, 1, n / 2, n / 2 + 1, n - 1};
  const int ms = static_cast<int>(scalars.size());
  MatrixXd E = MatrixXd::Zero(n, ms), columns(n, ms), got(ms, ms), want(ms, ms);
  for (int a = 0; a < ms; ++a) E(scalars[a], a) = 1.0;
  cholmod.solve(E.data(), columns.data(), ms);
  block.inverseBlock(scalars, got.data());
  for (int a = 0; a < ms; ++a)
    for (int b = 0; b < ms; ++b) want(a, b) = columns(scalars[a], b);
  EXPECT_LT((got - want).norm(), (GetParam().wellConditioned ? 1e-9 : 1e-5) * want.norm());
}

INSTANTIATE_TEST_SUITE_P(Datasets, DatasetHessian,
                         ::testing::Values(DatasetCase{"intel.g2o", true},
                                           DatasetCase{"smallGrid3D.g2o", true},
                                           DatasetCase{"sphere2500.g2o", true},
                                           DatasetCase{"parking-garage.g2o", false}),
                         [](const auto& info) {
                           std::string name = info.param.file;
                           name = name.substr(0, name.find('.'));
                           for (char& c : name)
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           return name;
                         });

}  // namespace
}  // namespace loopd
