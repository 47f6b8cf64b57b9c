// HessianLayout + NormalEquations against a dense JᵀJ / Jᵀr assembled directly from
// Factor::evaluate, and SparseCholesky against a dense Eigen LLT.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Dense>
#include <array>
#include <memory>
#include <random>
#include <stdexcept>
#include <vector>

#include "solvers/factors/between_factor_se2.h"
#include "solvers/factors/between_factor_se3.h"
#include "solvers/factors/landmark_factors.h"
#include "solvers/factors/prior_factors.h"
#include "solvers/graph/factor_graph.h"
#include "solvers/linear/hessian_layout.h"
#include "solvers/linear/normal_equations.h"
#include "solvers/linear/sparse_cholesky.h"

namespace loopd {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;

template <int N>
Eigen::Matrix<double, N, N> randomInformation(std::mt19937& rng) {
  std::uniform_real_distribution<double> off(-1.0, 1.0), diag(0.5, 3.0);
  Eigen::Matrix<double, N, N> L = Eigen::Matrix<double, N, N>::Zero();
  for (int r = 0; r < N; ++r) {
    for (int c = 0; c < r; ++c) L(r, c) = off(rng);
    L(r, r) = diag(rng);
  }
  return L * L.transpose();
}

struct Problem {
  FactorGraph graph;
  Values values;
};

constexpr int kPoses = 12;
const std::vector<std::pair<int, int>> kLoops = {{0, 6}, {2, 9}, {4, 11}, {1, 10}};

// A chain of poses with loop closures, two landmarks (one seen twice), and a prior on x0.
// Values are the truth perturbed, so every residual is non-zero.
Problem makeProblem2D(unsigned seed, bool withPrior) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> step(0.5, 1.5), turn(-0.8, 0.8), noise(-0.1, 0.1);
  Problem p;
  std::vector<SE2> truth = {SE2(0.0, 0.0, 0.0)};
  for (int i = 1; i < kPoses; ++i)
    truth.push_back(truth.back() * SE2(step(rng), 0.2 * noise(rng), turn(rng)));
  auto noisy = [&](const SE2& z) { return z * SE2(noise(rng), noise(rng), noise(rng)); };
  if (withPrior)
    p.graph.add(std::make_shared<PriorFactorSE2>(poseKey(0), truth[0], randomInformation<3>(rng)));
  for (int i = 0; i + 1 < kPoses; ++i)
    p.graph.add(std::make_shared<BetweenFactorSE2>(
        poseKey(i), poseKey(i + 1), noisy(truth[i].between(truth[i + 1])),
        randomInformation<3>(rng), FactorRole::Odometry));
  for (auto [i, j] : kLoops)
    p.graph.add(std::make_shared<BetweenFactorSE2>(
        poseKey(i), poseKey(j), noisy(truth[i].between(truth[j])), randomInformation<3>(rng)));
  const Vec2 l0(2.0, 3.0), l1(-1.0, 4.0);
  p.graph.add(std::make_shared<PosePointFactor2>(
      poseKey(3), landmarkKey(0), truth[3].transformTo(l0), randomInformation<2>(rng)));
  p.graph.add(std::make_shared<PosePointFactor2>(
      poseKey(8), landmarkKey(0), truth[8].transformTo(l0), randomInformation<2>(rng)));
  const Vec2 v = truth[5].transformTo(l1);
  p.graph.add(std::make_shared<BearingRangeFactor2>(poseKey(5), landmarkKey(1),
                                                    Vec2(std::atan2(v.y(), v.x()), v.norm()),
                                                    randomInformation<2>(rng)));
  const Vec2 w = truth[7].transformTo(l1);
  p.graph.add(std::make_shared<BearingRangeFactor2>(poseKey(7), landmarkKey(1),
                                                    Vec2(std::atan2(w.y(), w.x()), w.norm()),
                                                    randomInformation<2>(rng)));
  // Insert a landmark first so slot order differs from pose order.
  p.values.insertPoint2(landmarkKey(1), l1 + Vec2(noise(rng), noise(rng)));
  for (int i = 0; i < kPoses; ++i) p.values.insert(poseKey(i), noisy(truth[i]));
  p.values.insertPoint2(landmarkKey(0), l0 + Vec2(noise(rng), noise(rng)));
  return p;
}

Problem makeProblem3D(unsigned seed, bool withPrior) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto twist = [&](double trans, double rot) {
    Vec6 xi;
    for (int k = 0; k < 3; ++k) xi[k] = trans * u(rng);
    for (int k = 3; k < 6; ++k) xi[k] = rot * u(rng);
    return xi;
  };
  Problem p;
  std::vector<SE3> truth = {SE3()};
  for (int i = 1; i < kPoses; ++i) {
    Vec6 xi = twist(0.3, 0.4);
    xi[0] += 1.0;
    truth.push_back(truth.back() * expSE3(xi));
  }
  auto noisy = [&](const SE3& z) { return z * expSE3(twist(0.05, 0.05)); };
  if (withPrior)
    p.graph.add(std::make_shared<PriorFactorSE3>(poseKey(0), truth[0], randomInformation<6>(rng)));
  for (int i = 0; i + 1 < kPoses; ++i)
    p.graph.add(std::make_shared<BetweenFactorSE3>(
        poseKey(i), poseKey(i + 1), noisy(truth[i].between(truth[i + 1])),
        randomInformation<6>(rng), FactorRole::Odometry));
  for (auto [i, j] : kLoops)
    p.graph.add(std::make_shared<BetweenFactorSE3>(
        poseKey(i), poseKey(j), noisy(truth[i].between(truth[j])), randomInformation<6>(rng)));
  const Vec3 l0(2.0, 3.0, 1.0);
  for (int i : {3, 8, 10})
    p.graph.add(std::make_shared<PosePointFactor3>(
        poseKey(i), landmarkKey(0), truth[i].transformTo(l0), randomInformation<3>(rng)));
  p.values.insertPoint3(landmarkKey(0), l0 + Vec3(0.1 * u(rng), 0.1 * u(rng), 0.1 * u(rng)));
  for (int i = 0; i < kPoses; ++i) p.values.insert(poseKey(i), noisy(truth[i]));
  return p;
}

struct Dense {
  MatrixXd H;
  VectorXd g;
  double chi2 = 0.0, weighted = 0.0;
};

// Dense JᵀWJ and JᵀWr straight from Factor::evaluate, columns placed by slotOffset().
Dense denseNormalEquations(const FactorGraph& graph, const Values& values,
                           const HessianLayout& layout,
                           const std::vector<double>* weights = nullptr) {
  const int n = layout.dimension();
  Dense d;
  d.H = MatrixXd::Zero(n, n);
  d.g = VectorXd::Zero(n);
  for (int f = 0; f < graph.size(); ++f) {
    const Factor& factor = *graph[f];
    std::array<const double*, kMaxFactorKeys> x{};
    for (int k = 0; k < factor.size(); ++k) x[k] = values.data(values.slot(factor.key(k)));
    std::array<JacobianBlock, kMaxFactorKeys> jac{};
    double* J[kMaxFactorKeys];
    for (int i = 0; i < kMaxFactorKeys; ++i) J[i] = jac[i].data();
    VectorXd r(factor.dim());
    factor.evaluate(x.data(), r.data(), J);
    MatrixXd Jrow = MatrixXd::Zero(factor.dim(), n);
    for (int k = 0; k < factor.size(); ++k) {
      const int off = layout.slotOffset()[values.slot(factor.key(k))];
      if (off < 0) continue;
      const int dk = varDim(factor.varType(k));
      Jrow.middleCols(off, dk) = Eigen::Map<const MatrixXd>(J[k], factor.dim(), dk);
    }
    const double w = weights ? (*weights)[f] : 1.0;
    d.H += w * Jrow.transpose() * Jrow;
    d.g += w * Jrow.transpose() * r;
    d.chi2 += r.squaredNorm();
    d.weighted += w * r.squaredNorm();
  }
  return d;
}

// The slot whose columns contain scalar index i, or −1.
int slotOfColumn(const HessianLayout& layout, const Values& values, int i) {
  for (int s = 0; s < values.size(); ++s) {
    const int off = layout.slotOffset()[s];
    if (off >= 0 && i >= off && i < off + varDim(values.type(s))) return s;
  }
  return -1;
}

// The layout's pattern is a valid upper CSC (plus whole diagonal blocks), offsets tile
// [0, n), and every stored value equals the dense H entry; upper entries rebuild H exactly.
void expectMatchesDense(const HessianLayout& layout, const NormalEquations& ne,
                        const Values& values, const Dense& dense, const std::vector<char>& fixed) {
  const int n = layout.dimension();
  ASSERT_EQ(dense.H.rows(), n);
  const auto& cs = layout.columnStart();
  const auto& ri = layout.rowIndex();
  const auto& hv = ne.hessian();
  ASSERT_EQ(static_cast<int>(cs.size()), n + 1);
  ASSERT_EQ(cs[0], 0);
  ASSERT_EQ(cs[n], layout.nonZeros());
  ASSERT_EQ(static_cast<long>(hv.size()), layout.nonZeros());
  ASSERT_EQ(static_cast<int>(ne.gradient().size()), n);

  // Offsets: fixed slots −1, the others tile [0, n) without overlap.
  std::vector<int> covered(n, 0);
  int expectedDim = 0;
  for (int s = 0; s < values.size(); ++s) {
    const int off = layout.slotOffset()[s];
    if (!fixed.empty() && fixed[s]) {
      EXPECT_EQ(off, -1) << "fixed slot " << s << " has columns";
      continue;
    }
    ASSERT_GE(off, 0);
    expectedDim += varDim(values.type(s));
    for (int k = 0; k < varDim(values.type(s)); ++k) ++covered[off + k];
  }
  EXPECT_EQ(expectedDim, n);
  for (int i = 0; i < n; ++i) EXPECT_EQ(covered[i], 1) << "column " << i;

  const double scale = 1.0 + dense.H.cwiseAbs().maxCoeff();
  MatrixXd upper = MatrixXd::Zero(n, n);
  for (int c = 0; c < n; ++c) {
    const int sc = slotOfColumn(layout, values, c);
    EXPECT_EQ(layout.columnLength(sc), cs[c + 1] - cs[c]);
    for (int p = cs[c]; p < cs[c + 1]; ++p) {
      const int r = ri[p];
      ASSERT_GE(r, 0);
      ASSERT_LT(r, n);
      if (p > cs[c]) {
        EXPECT_GT(r, ri[p - 1]) << "rows not strictly increasing in column " << c;
      }
      if (r > c) {
        EXPECT_EQ(slotOfColumn(layout, values, r), sc) << "lower entry outside the diagonal block";
      }
      // Every stored entry (also the lower part of diagonal blocks) is the true H entry.
      EXPECT_NEAR(hv[p], dense.H(r, c), 1e-10 * scale) << "H(" << r << "," << c << ")";
      if (r <= c) upper(r, c) = hv[p];
    }
  }
  const MatrixXd rebuilt = upper + upper.transpose() - MatrixXd(upper.diagonal().asDiagonal());
  EXPECT_LT((rebuilt - dense.H).cwiseAbs().maxCoeff(), 1e-10 * scale)
      << "the upper triangle of the CSC does not reproduce H (missing pattern entries?)";

  const auto& diag = layout.diagonalPositions();
  ASSERT_EQ(static_cast<int>(diag.size()), n);
  for (int c = 0; c < n; ++c) {
    EXPECT_EQ(ri[diag[c]], c);
    EXPECT_GE(diag[c], cs[c]);
    EXPECT_LT(diag[c], cs[c + 1]);
  }

  const VectorXd g = Eigen::Map<const VectorXd>(ne.gradient().data(), n);
  EXPECT_LT((g - dense.g).cwiseAbs().maxCoeff(), 1e-10 * (1.0 + dense.g.cwiseAbs().maxCoeff()));
}

// Dense copy of the assembled H from the upper triangle of the CSC.
MatrixXd denseFromCsc(const HessianLayout& layout, const std::vector<double>& values) {
  const int n = layout.dimension();
  MatrixXd H = MatrixXd::Zero(n, n);
  for (int c = 0; c < n; ++c)
    for (int p = layout.columnStart()[c]; p < layout.columnStart()[c + 1]; ++p) {
      const int r = layout.rowIndex()[p];
      if (r <= c) H(r, c) = H(c, r) = values[p];
    }
  return H;
}

class LinearTest : public ::testing::TestWithParam<int> {
 protected:
  Problem make(unsigned seed, bool withPrior) const {
    return GetParam() == 2 ? makeProblem2D(seed, withPrior) : makeProblem3D(seed, withPrior);
  }
  int poseDim() const { return GetParam() == 2 ? 3 : 6; }
};

TEST_P(LinearTest, NormalEquationsMatchDenseJacobianProducts) {
  for (unsigned seed : {1u, 2u, 3u}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    const Problem p = make(seed, true);
    const HessianLayout layout(p.graph, p.values, {});
    int total = 0;
    for (int s = 0; s < p.values.size(); ++s) total += varDim(p.values.type(s));
    EXPECT_EQ(layout.dimension(), total);
    NormalEquations ne(layout);
    const LinearizationCost cost = ne.build(p.graph, p.values);
    const Dense dense = denseNormalEquations(p.graph, p.values, layout);
    expectMatchesDense(layout, ne, p.values, dense, {});
    EXPECT_GT(cost.chi2, 0.0);
    EXPECT_NEAR(cost.chi2, dense.chi2, 1e-10 * dense.chi2);
    EXPECT_NEAR(cost.chi2, p.graph.chi2(p.values), 1e-10 * dense.chi2);
    EXPECT_DOUBLE_EQ(cost.weighted, cost.chi2);
    const LinearizationCost c2 = ne.cost(p.graph, p.values);
    EXPECT_NEAR(c2.chi2, cost.chi2, 1e-12 * cost.chi2);
    std::vector<double> perFactor;
    ne.factorChi2(p.graph, p.values, perFactor);
    ASSERT_EQ(static_cast<int>(perFactor.size()), p.graph.size());
    double sum = 0.0;
    for (int f = 0; f < p.graph.size(); ++f) {
      EXPECT_NEAR(perFactor[f], p.graph[f]->chi2(p.values), 1e-12 * (1.0 + perFactor[f]));
      sum += perFactor[f];
    }
    EXPECT_NEAR(sum, cost.chi2, 1e-10 * cost.chi2);

    // A second build at other values reuses the layout and overwrites (does not accumulate).
    Values moved = p.values;
    std::vector<double> step(layout.dimension(), 0.01);
    moved.retractAll(layout.slotOffset(), step.data());
    ne.build(p.graph, moved);
    expectMatchesDense(layout, ne, moved, denseNormalEquations(p.graph, moved, layout), {});
  }
}

TEST_P(LinearTest, WeightedBuild) {
  const Problem p = make(4, true);
  const HessianLayout layout(p.graph, p.values, {});
  std::vector<double> w(p.graph.size());
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 2.0);
  for (double& x : w) x = u(rng);
  w[3] = 0.0;  // a zero weight drops the factor from H and g
  NormalEquations ne(layout);
  const LinearizationCost cost = ne.build(p.graph, p.values, w.data());
  const Dense dense = denseNormalEquations(p.graph, p.values, layout, &w);
  expectMatchesDense(layout, ne, p.values, dense, {});
  EXPECT_NEAR(cost.chi2, dense.chi2, 1e-10 * dense.chi2);
  EXPECT_NEAR(cost.weighted, dense.weighted, 1e-10 * dense.weighted);
  const LinearizationCost c2 = ne.cost(p.graph, p.values, w.data());
  EXPECT_NEAR(c2.weighted, dense.weighted, 1e-10 * dense.weighted);
}

TEST_P(LinearTest, FixedFirstPoseHasNoColumns) {
  const Problem p = make(6, false);
  std::vector<char> fixed(p.values.size(), 0);
  const int s0 = p.values.slot(poseKey(0));
  fixed[s0] = 1;
  const HessianLayout layout(p.graph, p.values, fixed);
  int total = 0;
  for (int s = 0; s < p.values.size(); ++s) total += varDim(p.values.type(s));
  EXPECT_EQ(layout.dimension(), total - poseDim());
  EXPECT_EQ(layout.slotOffset()[s0], -1);
  for (int f = 0; f < p.graph.size(); ++f)
    for (int a = 0; a < p.graph[f]->size(); ++a)
      for (int b = 0; b < p.graph[f]->size(); ++b)
        if (layout.factorSlot(f, a) == s0 || layout.factorSlot(f, b) == s0) {
          EXPECT_EQ(layout.blockStart(f, a, b), -1);
        }
  NormalEquations ne(layout);
  ne.build(p.graph, p.values);
  const Dense dense = denseNormalEquations(p.graph, p.values, layout);
  expectMatchesDense(layout, ne, p.values, dense, fixed);
  // The reduced H is the full H with x0's rows and columns removed.
  const HessianLayout full(p.graph, p.values, {});
  const Dense fullDense = denseNormalEquations(p.graph, p.values, full);
  for (int s = 0; s < p.values.size(); ++s)
    for (int t = 0; t < p.values.size(); ++t) {
      if (s == s0 || t == s0) continue;
      const int ds = varDim(p.values.type(s)), dt = varDim(p.values.type(t));
      EXPECT_LT((dense.H.block(layout.slotOffset()[s], layout.slotOffset()[t], ds, dt) -
                 fullDense.H.block(full.slotOffset()[s], full.slotOffset()[t], ds, dt))
                    .cwiseAbs()
                    .maxCoeff(),
                1e-10 * (1.0 + fullDense.H.cwiseAbs().maxCoeff()));
    }
  // And it is positive definite: the gauge is gone.
  EXPECT_EQ(dense.H.llt().info(), Eigen::Success);
}

TEST_P(LinearTest, LayoutRejectsMissingKeyAndWrongType) {
  const Problem p = make(7, true);
  Values missing;
  for (int s = 0; s < p.values.size(); ++s)
    if (p.values.key(s) != poseKey(5)) missing.insertFrom(p.values, s);
  EXPECT_THROW(HessianLayout(p.graph, missing, {}), std::invalid_argument);
  Values wrong;
  for (int s = 0; s < p.values.size(); ++s) {
    if (p.values.key(s) == poseKey(5))
      wrong.insertPoint3(poseKey(5), Vec3::Zero());
    else
      wrong.insertFrom(p.values, s);
  }
  EXPECT_THROW(HessianLayout(p.graph, wrong, {}), std::invalid_argument);
}

void expectSolveMatchesDense(const HessianLayout& layout, const NormalEquations& ne,
                             FactorizationKind kind, bool natural) {
  const int n = layout.dimension();
  const MatrixXd H = denseFromCsc(layout, ne.hessian());
  const VectorXd g = Eigen::Map<const VectorXd>(ne.gradient().data(), n);
  const Eigen::LLT<MatrixXd> llt(H);
  ASSERT_EQ(llt.info(), Eigen::Success);

  SparseCholesky chol(kind);
  EXPECT_FALSE(chol.analyzed());
  chol.analyze(n, layout.columnStart(), layout.rowIndex(), natural);
  EXPECT_TRUE(chol.analyzed());
  EXPECT_EQ(chol.dimension(), n);
  ASSERT_TRUE(chol.factorize(ne.hessian()));
  if (kind == FactorizationKind::Supernodal) {
    EXPECT_TRUE(chol.isSupernodal());
  }
  if (kind == FactorizationKind::Simplicial) {
    EXPECT_FALSE(chol.isSupernodal());
  }
  EXPECT_GT(chol.factorNonZeros(), 0);

  VectorXd x(n);
  chol.solve(g.data(), x.data());
  const VectorXd xd = llt.solve(g);
  EXPECT_LT((x - xd).norm(), 1e-9 * (1.0 + xd.norm()));
  EXPECT_LT((H * x - g).norm(), 1e-9 * (1.0 + g.norm()));

  // Several right-hand sides at once.
  MatrixXd B = MatrixXd::Random(n, 3);
  B.col(0) = g;
  MatrixXd X(n, 3);
  chol.solve(B.data(), X.data(), 3);
  EXPECT_LT((X - llt.solve(B)).norm(), 1e-9 * (1.0 + X.norm()));
}

TEST_P(LinearTest, SparseCholeskyMatchesDenseLLT) {
  for (bool prior : {true, false}) {
    const Problem p = make(8, prior);
    std::vector<char> fixed;
    if (!prior) {
      fixed.assign(p.values.size(), 0);
      fixed[p.values.slot(poseKey(0))] = 1;
    }
    const HessianLayout layout(p.graph, p.values, fixed);
    NormalEquations ne(layout);
    ne.build(p.graph, p.values);
    for (FactorizationKind kind :
         {FactorizationKind::Auto, FactorizationKind::Supernodal, FactorizationKind::Simplicial})
      for (bool natural : {true, false}) {
        SCOPED_TRACE(::testing::Message() << "prior " << prior << " kind " << static_cast<int>(kind)
                                          << " natural " << natural);
        expectSolveMatchesDense(layout, ne, kind, natural);
      }
  }
}

TEST_P(LinearTest, RefactorizeReusesAnalysisAndGaussNewtonStepDescends) {
  Problem p = make(9, true);
  const HessianLayout layout(p.graph, p.values, {});
  NormalEquations ne(layout);
  SparseCholesky chol(FactorizationKind::Supernodal);
  chol.analyze(layout.dimension(), layout.columnStart(), layout.rowIndex());
  double prev = ne.cost(p.graph, p.values).chi2;
  for (int it = 0; it < 4; ++it) {
    ne.build(p.graph, p.values);
    ASSERT_TRUE(chol.factorize(ne.hessian()));
    const MatrixXd H = denseFromCsc(layout, ne.hessian());
    std::vector<double> dx(layout.dimension());
    chol.solve(ne.gradient().data(), dx.data());
    const VectorXd xd =
        H.llt().solve(Eigen::Map<const VectorXd>(ne.gradient().data(), layout.dimension()));
    EXPECT_LT((Eigen::Map<const VectorXd>(dx.data(), dx.size()) - xd).norm(),
              1e-9 * (1.0 + xd.norm()));
    for (double& v : dx) v = -v;  // g = Jᵀr, step = −H⁻¹g
    p.values.retractAll(layout.slotOffset(), dx.data());
    const double now = ne.cost(p.graph, p.values).chi2;
    EXPECT_LT(now, prev) << "iteration " << it;
    prev = now;
  }
}

TEST_P(LinearTest, FactorizeReportsIndefinite) {
  const Problem p = make(10, true);
  const HessianLayout layout(p.graph, p.values, {});
  NormalEquations ne(layout);
  ne.build(p.graph, p.values);
  for (FactorizationKind kind :
       {FactorizationKind::Auto, FactorizationKind::Supernodal, FactorizationKind::Simplicial}) {
    SparseCholesky chol(kind);
    chol.analyze(layout.dimension(), layout.columnStart(), layout.rowIndex());
    std::vector<double> bad = ne.hessian();
    const int mid = layout.dimension() / 2;
    bad[layout.diagonalPositions()[mid]] =
        -1e3 * (1.0 + std::abs(bad[layout.diagonalPositions()[mid]]));
    EXPECT_FALSE(chol.factorize(bad)) << "kind " << static_cast<int>(kind);
    // Recovers with a good matrix on the same analysis.
    EXPECT_TRUE(chol.factorize(ne.hessian())) << "kind " << static_cast<int>(kind);
    // Negative definite, too.
    std::vector<double> neg = ne.hessian();
    for (double& v : neg) v = -v;
    EXPECT_FALSE(chol.factorize(neg));
  }
}

INSTANTIATE_TEST_SUITE_P(PoseGraph, LinearTest, ::testing::Values(2, 3),
                         [](const ::testing::TestParamInfo<int>& i) {
                           return std::to_string(i.param) + "D";
                         });

TEST(SparseCholesky, SmallHandBuiltMatrices) {
  // [[4, 2, 0], [2, 5, 1], [0, 1, 3]]: SPD, upper triangle CSC.
  const std::vector<int> cs = {0, 1, 3, 5};
  const std::vector<int> ri = {0, 0, 1, 1, 2};
  const std::vector<double> spd = {4.0, 2.0, 5.0, 1.0, 3.0};
  Eigen::Matrix3d A;
  A << 4, 2, 0, 2, 5, 1, 0, 1, 3;
  for (FactorizationKind kind :
       {FactorizationKind::Auto, FactorizationKind::Supernodal, FactorizationKind::Simplicial}) {
    SparseCholesky chol(kind);
    chol.analyze(3, cs, ri);
    ASSERT_TRUE(chol.factorize(spd));
    const Eigen::Vector3d b(1.0, -2.0, 3.0);
    Eigen::Vector3d x;
    chol.solve(b.data(), x.data());
    EXPECT_LT((x - A.llt().solve(b)).norm(), 1e-12);
    // [[1, 2, 0], [2, 1, 0], [0, 0, 1]] is indefinite (eigenvalues 3, −1, 1).
    EXPECT_FALSE(chol.factorize({1.0, 2.0, 1.0, 0.0, 1.0}));
    // Singular: [[1, 1, 0], [1, 1, 0], [0, 0, 1]].
    EXPECT_FALSE(chol.factorize({1.0, 1.0, 1.0, 0.0, 1.0}));
    ASSERT_TRUE(chol.factorize(spd));
  }
  SparseCholesky unanalyzed;
  EXPECT_THROW(unanalyzed.factorize(spd), std::logic_error);
  // Re-analysis of a new pattern on the same object.
  SparseCholesky chol;
  chol.analyze(3, cs, ri);
  ASSERT_TRUE(chol.factorize(spd));
  chol.analyze(2, {0, 1, 2}, {0, 1});
  ASSERT_TRUE(chol.factorize({2.0, 8.0}));
  const double b[2] = {2.0, 4.0};
  double x[2];
  chol.solve(b, x);
  EXPECT_NEAR(x[0], 1.0, 1e-15);
  EXPECT_NEAR(x[1], 0.5, 1e-15);
}

}  // namespace
}  // namespace loopd
