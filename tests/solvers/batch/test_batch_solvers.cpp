// Every batch solver reaches the best known optimum (../shared/REFERENCE.md) on every
// dataset, from the default linear initialisation.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include <cmath>
#include <string>

#include "robust/backend_registry.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/problem/pose_graph_problem.h"

namespace loopd {
namespace {

struct Case {
  const char* file;
  double bestChi2;  // REFERENCE.md; 0 = none published (check convergence only)
};

const Case kCases[] = {
    {"intel.g2o", 45.004696},
    {"manhattan.g2o", 3549.0368},
    {"city10000.g2o", 511.98516},
    {"CSAIL.g2o", 40.555129},
    {"MIT.g2o", 41.163269},
    {"kitti_00.g2o", 98.322012},
    {"sphere2500.g2o", 1351.4019},
    {"parking-garage.g2o", 1.2683848},
    {"torus3D.g2o", 24235.274},
    {"smallGrid3D.g2o", 1035.8507},
    {"tinyGrid3D.g2o", 18.627819},
    {"w100.graph", 0.0},
    // Not in REFERENCE.md: the lowest chi2 known, which isam2 online and every batch solver
    // from the default start reach (headings from the landmark sightings, landmark_headings.h).
    // With odometry-only headings the batch solvers stopped in a local minimum, 227029.94.
    {"victoria_park.txt", 6184.1202},
};

std::string caseName(const testing::TestParamInfo<std::tuple<std::string, Case>>& info) {
  std::string name = std::get<0>(info.param) + "_" + std::get<1>(info.param).file;
  for (char& c : name)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return name;
}

class BatchSolverTest : public testing::TestWithParam<std::tuple<std::string, Case>> {};

TEST_P(BatchSolverTest, ReachesBestKnownOptimum) {
  const auto& [solver, c] = GetParam();
  const io::Dataset ds = io::readDataset(std::string(LOOPD_DATASETS_DIR) + "/" + c.file);
  const PoseGraphProblem problem = buildProblem(ds);
  auto backend = makeBackend(solver);
  backend->update(wholeProblemUpdate(problem));
  const double chi2 = backend->chi2();
  EXPECT_TRUE(backend->summary().converged) << backend->summary().stopReason;
  EXPECT_FALSE(backend->summary().budgetSpent);
  if (c.bestChi2 > 0.0) {
    EXPECT_LE(chi2, c.bestChi2 * (1.0 + 1e-4)) << c.file;
    // Not below the best known optimum by more than its printed rounding.
    EXPECT_GE(chi2, c.bestChi2 * (1.0 - 1e-6)) << c.file;
  } else {
    EXPECT_LT(chi2, backend->summary().initialChi2) << c.file;
  }
}

INSTANTIATE_TEST_SUITE_P(AllDatasets, BatchSolverTest,
                         testing::Combine(testing::Values("lm", "gn", "dogleg"),
                                          testing::ValuesIn(kCases)),
                         caseName);

TEST(BatchSolver, FileStartStillReachesOptimumOnEasyData) {
  const io::Dataset ds = io::readDataset(std::string(LOOPD_DATASETS_DIR) + "/intel.g2o");
  const PoseGraphProblem problem = buildProblem(ds);
  BackendOptions o;
  o.linearInitialization = false;
  auto backend = makeBackend("lm", o);
  backend->update(wholeProblemUpdate(problem));
  EXPECT_LE(backend->chi2(), 45.004696 * (1.0 + 1e-4));
}

// A solve cut short by maxIterations says so (SolveSummary::budgetSpent: the server's pause
// resumes it); another optimize() goes on from there.
TEST(BatchSolver, AStopOnTheIterationBudgetIsReportedAndResumable) {
  const io::Dataset ds = io::readDataset(std::string(LOOPD_DATASETS_DIR) + "/intel.g2o");
  const PoseGraphProblem problem = buildProblem(ds);
  for (const std::string solver : {"lm", "gn", "dogleg"}) {
    BackendOptions o;
    o.linearInitialization = false;  // the file's start: more than one iteration
    o.maxIterations = 1;
    auto backend = makeBackend(solver, o);
    backend->update(wholeProblemUpdate(problem));
    EXPECT_TRUE(backend->summary().budgetSpent) << solver;
    EXPECT_EQ(backend->summary().stopReason, "iteration limit") << solver;
    const double first = backend->chi2();
    for (int round = 0; round < 200 && backend->summary().budgetSpent; ++round) backend->optimize();
    EXPECT_FALSE(backend->summary().budgetSpent) << solver;
    EXPECT_LT(backend->chi2(), first) << solver;
    EXPECT_LE(backend->chi2(), 45.004696 * (1.0 + 1e-4)) << solver;
  }
}

TEST(BatchSolver, MarginalsAreSymmetricPositiveDefinite) {
  const io::Dataset ds = io::readDataset(std::string(LOOPD_DATASETS_DIR) + "/tinyGrid3D.g2o");
  const PoseGraphProblem problem = buildProblem(ds);
  auto backend = makeBackend("lm");
  backend->update(wholeProblemUpdate(problem));
  std::vector<Key> keys;
  for (Key k : backend->estimate().keys())
    if (k != problem.firstPose) keys.push_back(k);
  const Eigen::MatrixXd joint = backend->marginalCovariance(keys);
  ASSERT_EQ(joint.rows(), 6 * static_cast<int>(keys.size()));
  EXPECT_TRUE(joint.isApprox(joint.transpose(), 1e-9));
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(joint);
  EXPECT_GT(eig.eigenvalues().minCoeff(), 0.0);
  // Per-key marginals equal the joint's diagonal blocks.
  const auto blocks = backend->marginals(keys);
  for (size_t i = 0; i < keys.size(); ++i)
    EXPECT_TRUE(blocks[i].isApprox(joint.block<6, 6>(6 * i, 6 * i), 1e-9));
}

TEST(BatchSolver, RejectsUpdatesThatReferToUnknownThings) {
  const io::Dataset ds = io::readDataset(std::string(LOOPD_DATASETS_DIR) + "/tinyGrid3D.g2o");
  const PoseGraphProblem problem = buildProblem(ds);
  auto backend = makeBackend("lm");
  BackendUpdate missingValue;
  missingValue.factors = problem.graph.factors();  // no initial values
  EXPECT_THROW(backend->update(missingValue), std::invalid_argument);
  EXPECT_EQ(backend->graph().size(), 0);
  backend->update(wholeProblemUpdate(problem));
  BackendUpdate unknownRemoval;
  unknownRemoval.removals = {99999};
  EXPECT_THROW(backend->update(unknownRemoval), std::invalid_argument);
  BackendUpdate duplicate;
  duplicate.factors = {problem.graph[0]};
  EXPECT_THROW(backend->update(duplicate), std::invalid_argument);
  EXPECT_EQ(backend->graph().size(), problem.graph.size());
}

TEST(BatchSolver, RemovingAFactorEqualsNeverAddingIt) {
  const io::Dataset ds = io::readDataset(std::string(LOOPD_DATASETS_DIR) + "/smallGrid3D.g2o");
  const PoseGraphProblem problem = buildProblem(ds);
  const int dropped = problem.graph.size() - 1;  // a loop closure at the end of the file
  auto withRemoval = makeBackend("lm");
  const BackendUpdate all = wholeProblemUpdate(problem);
  withRemoval->update(all);
  BackendUpdate removal;
  removal.removals = {problem.graph[dropped]->id()};
  withRemoval->update(removal);

  auto without = makeBackend("lm");
  BackendUpdate fewer = all;
  fewer.factors.erase(fewer.factors.begin() + dropped);
  without->update(fewer);
  EXPECT_NEAR(withRemoval->chi2(), without->chi2(), 1e-6 * without->chi2());
}

}  // namespace
}  // namespace loopd
