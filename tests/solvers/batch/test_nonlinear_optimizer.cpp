// Factors of weight exactly 0 leave the Hessian's pattern (NonlinearOptimizer::fitPattern):
// solving and marginals with them zeroed equal the graph without them, and the pattern comes
// back when they are weighted again.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "solvers/batch/nonlinear_optimizer.h"
#include "solvers/init/initialization.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/linear/normal_equations.h"
#include "solvers/marginals/batch_marginals.h"
#include "solvers/problem/pose_graph_problem.h"

namespace loopd {
namespace {

struct ZeroedClosures {
  PoseGraphProblem problem;
  Values start;
  std::vector<char> fixed;
  std::vector<double> weights;  // every other loop closure 0
  FactorGraph kept;             // the graph without them
};

ZeroedClosures zeroEveryOtherClosure(const char* file) {
  ZeroedClosures z;
  z.problem = buildProblem(io::readDataset(std::string(LOOPD_DATASETS_DIR) + "/" + file));
  const FactorGraph& g = z.problem.graph;
  z.start = initializeLinear(g, z.problem.initial, z.problem.firstPose);
  z.fixed.assign(z.start.size(), 0);
  z.fixed[z.start.slot(z.problem.firstPose)] = 1;
  z.weights.assign(g.size(), 1.0);
  int closures = 0;
  for (int f = 0; f < g.size(); ++f) {
    if (g[f]->role() == FactorRole::LoopClosure && closures++ % 2 == 0)
      z.weights[f] = 0.0;
    else
      z.kept.add(g[f]);
  }
  return z;
}

TEST(NonlinearOptimizer, ZeroWeightFactorsLeaveThePatternAndComeBack) {
  ZeroedClosures z = zeroEveryOtherClosure("intel.g2o");
  NonlinearOptimizer full(z.problem.graph, z.start, z.fixed);
  const long allEntries = full.layout().nonZeros();
  NonlinearOptimizer reduced(z.kept, z.start, z.fixed);
  ASSERT_LT(reduced.layout().nonZeros(), allEntries);

  Values a = z.start, b = z.start;
  const OptimizerResult ra = full.optimize(a, z.weights.data());
  const OptimizerResult rb = reduced.optimize(b);
  EXPECT_EQ(full.layout().nonZeros(), reduced.layout().nonZeros());
  EXPECT_NEAR(ra.finalWeightedCost, rb.finalChi2, 1e-9 * rb.finalChi2);
  EXPECT_NEAR(z.kept.chi2(a), rb.finalChi2, 1e-9 * rb.finalChi2);

  // Every factor weighted again: the whole pattern, and the full problem's optimum.
  Values c = z.start, d = z.start;
  const OptimizerResult rc = full.optimize(c);
  EXPECT_EQ(full.layout().nonZeros(), allEntries);
  NonlinearOptimizer fresh(z.problem.graph, z.start, z.fixed);
  const OptimizerResult rd = fresh.optimize(d);
  EXPECT_NEAR(rc.finalChi2, rd.finalChi2, 1e-9 * rd.finalChi2);
}

TEST(NonlinearOptimizer, MarginalsFollowTheWeightsPattern) {
  ZeroedClosures z = zeroEveryOtherClosure("smallGrid3D.g2o");
  NonlinearOptimizer full(z.problem.graph, z.start, z.fixed);
  NonlinearOptimizer reduced(z.kept, z.start, z.fixed);
  Values solved = z.start;
  reduced.optimize(solved);
  std::vector<std::vector<Key>> sets;
  const std::vector<Key> keys = solved.keys();
  for (size_t i = 1; i + 1 < keys.size(); i += 7) sets.push_back({keys[i], keys[i + 1]});
  // The full optimizer's first factorization has every factor; the weighted call must lay
  // out (and locate its keys in) the reduced pattern.
  ASSERT_TRUE(full.factorizeAt(solved));
  const auto withWeights = jointMarginals(full, solved, sets, z.weights.data());
  const auto expected = jointMarginals(reduced, solved, sets);
  ASSERT_EQ(withWeights.size(), expected.size());
  for (size_t s = 0; s < sets.size(); ++s)
    EXPECT_TRUE(withWeights[s].isApprox(expected[s], 1e-8)) << "set " << s;
}

// The hook before each set is where a caller that must yield (the GNC look under the server)
// gives up: once per set, before its block, and a throw from it leaves jointMarginals.
TEST(NonlinearOptimizer, JointMarginalsCallTheirHookBeforeEachSet) {
  ZeroedClosures z = zeroEveryOtherClosure("smallGrid3D.g2o");
  NonlinearOptimizer reduced(z.kept, z.start, z.fixed);
  Values solved = z.start;
  reduced.optimize(solved);
  const std::vector<Key> keys = solved.keys();
  const std::vector<std::vector<Key>> sets = {{keys[1], keys[2]}, {keys[5]}, {keys[3], keys[9]}};
  int calls = 0;
  const auto hooked = jointMarginals(reduced, solved, sets, nullptr, [&] { ++calls; });
  EXPECT_EQ(calls, 3);
  const auto plain = jointMarginals(reduced, solved, sets);
  for (size_t s = 0; s < sets.size(); ++s) EXPECT_EQ(hooked[s], plain[s]) << "set " << s;
  calls = 0;
  struct GiveUp {};
  EXPECT_THROW(jointMarginals(reduced, solved, sets, nullptr,
                              [&] {
                                if (++calls == 2) throw GiveUp{};
                              }),
               GiveUp);
  EXPECT_EQ(calls, 2);
}

TEST(NormalEquations, AWeightOnAFactorOutsideTheLayoutIsAnError) {
  ZeroedClosures z = zeroEveryOtherClosure("smallGrid3D.g2o");
  std::vector<char> active(z.problem.graph.size());
  for (size_t f = 0; f < active.size(); ++f) active[f] = z.weights[f] != 0.0;
  const HessianLayout layout(z.problem.graph, z.start, z.fixed, active);
  NormalEquations eq(layout);
  EXPECT_NO_THROW(eq.build(z.problem.graph, z.start, z.weights.data()));
  EXPECT_THROW(eq.build(z.problem.graph, z.start), std::logic_error);
  EXPECT_THROW(HessianLayout(z.problem.graph, z.start, z.fixed, std::vector<char>(3, 1)),
               std::invalid_argument);
}

}  // namespace
}  // namespace loopd
