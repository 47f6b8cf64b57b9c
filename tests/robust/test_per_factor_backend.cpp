// The robust handling a sender asks for per factor (the wire's `robust`), applied around any
// solver: a kernel, sc or mm on chosen closures, "none" to force trust, the solver's own
// handling otherwise.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <set>
#include <stdexcept>
#include <string>

#include "robust/backend_registry.h"
#include "robust/held_kernel_factor.h"
#include "robust/per_factor_backend.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/problem/incremental_schedule.h"
#include "solvers/problem/initial_guess.h"
#include "solvers/problem/pose_graph_problem.h"
#include "tests/robust/dataset_prefix.h"
#include "tools/loopd-outliers/outlier_generator.h"
#include "tools/loopd-solve/online_run.h"

namespace loopd {
namespace {

// intel with 30 random wrong loop closures (file edge indices ≥ inlierEdges).
struct Data {
  PoseGraphProblem problem;
  std::set<FactorId> outliers;
  double optimum = 0.0;  // chi2 of the outlier-free optimum
};

Data intelWithOutliers() {
  const io::Dataset clean = io::readDataset(std::string(LOOPD_DATASETS_DIR) + "/intel.g2o");
  tools::OutlierOptions o;
  o.count = 30;
  o.seed = 3;
  const tools::OutlierResult r = tools::addOutliers(clean, o);
  Data d;
  d.problem = buildProblem(r.graph);
  d.outliers.insert(r.outliers.begin(), r.outliers.end());
  auto lm = makeBackend("lm");
  const PoseGraphProblem p = buildProblem(clean);
  lm->update(wholeProblemUpdate(p));
  d.optimum = lm->chi2();
  return d;
}

// Every factor's request: `outlier` for the wrong closures, `inlier` for the true ones.
void request(const Data& d, const std::string& outlier, const std::string& inlier = "") {
  for (const auto& f : d.problem.graph.factors())
    if (isUncertain(f->role()))
      std::const_pointer_cast<Factor>(f)->setRobustRequest(
          {d.outliers.count(f->id()) ? outlier : inlier, 0.0});
}

std::unique_ptr<PerFactorRobustBackend> feed(const std::string& solver, const Data& d) {
  auto b = std::make_unique<PerFactorRobustBackend>(makeBackend(solver));
  tools::runOnline(*b, d.problem, /*quiet=*/true);
  return b;
}

double inlierChi2(const Backend& b, const Data& d) {
  double c = 0.0;
  for (const auto& f : d.problem.graph.factors())
    if (!d.outliers.count(f->id())) c += f->chi2(b.estimate());
  return c;
}

std::set<FactorId> rejectedSet(const Backend& b) {
  const auto r = b.rejected();
  return {r.begin(), r.end()};
}

TEST(PerFactorRobust, KernelRequestedOnTheWrongClosuresRejectsThemUnderPlainIsam2) {
  const Data d = intelWithOutliers();
  request(d, "");
  const auto plain = feed("isam2", d);
  EXPECT_GT(inlierChi2(*plain, d), 2.0 * d.optimum);  // isam2 alone takes them all
  EXPECT_TRUE(plain->rejected().empty());

  for (const char* kernel : {"dcs", "mm"}) {
    request(d, kernel);
    const auto b = feed("isam2", d);
    EXPECT_EQ(rejectedSet(*b), d.outliers) << kernel;
    EXPECT_LT(inlierChi2(*b, d), 1.01 * d.optimum) << kernel;
    EXPECT_EQ(b->name(), "isam2");
  }
}

// dcs asked on every closure under plain isam2 (the server's `--solver isam2`): optimize()
// descends Σρ (isam2's heldDescent holds each kernel at its weight), as under `--solver dcs`.
// It fell back to Levenberg–Marquardt on rᵀr of the re-weighted residuals, which falls as a
// closure is pulled away: sphere2500's first 500 poses at once ended with 423 of their 450
// closures (all true) rejected.
TEST(PerFactorRobust, KernelRequestsUnderPlainIsam2DescendTheirObjective) {
  PoseGraphProblem p = buildProblem(test::loadPrefix("sphere2500.g2o:500"));
  for (const auto& f : p.graph.factors())
    if (isUncertain(f->role())) std::const_pointer_cast<Factor>(f)->setRobustRequest({"dcs", 0.0});
  auto b = std::make_unique<PerFactorRobustBackend>(makeBackend("isam2"));
  b->update(wholeProblemUpdate(p));
  b->optimize();
  EXPECT_LE(b->rejected().size(), 2u);
  auto dcs = makeBackend("dcs");
  dcs->update(wholeProblemUpdate(buildProblem(test::loadPrefix("sphere2500.g2o:500"))));
  dcs->optimize();
  EXPECT_NEAR(b->chi2(), dcs->chi2(), 1e-6 * dcs->chi2());
}

TEST(PerFactorRobust, SwitchableRequestGetsItsOwnSwitchVariables) {
  const Data d = intelWithOutliers();
  request(d, "sc");
  const auto b = feed("isam2", d);
  EXPECT_EQ(rejectedSet(*b), d.outliers);
  int switches = 0;
  for (Key k : b->estimate().keys())
    if (keyKind(k) == KeyKind::Switch) {
      ++switches;
      EXPECT_GE(keyIndex(k), PerFactorRobustBackend::kSwitchIndexBase);
    }
  EXPECT_EQ(switches, static_cast<int>(d.outliers.size()));
  // graph() is what was sent: no switch priors, the original factors, their plain chi2.
  EXPECT_EQ(b->graph().size(), d.problem.graph.size());
  EXPECT_NEAR(b->chi2(), d.problem.graph.chi2(b->estimate()), 1e-9 * b->chi2());
}

TEST(PerFactorRobust, NoneForcesTrustUnderARobustSolver) {
  const Data d = intelWithOutliers();
  request(d, "");
  EXPECT_EQ(rejectedSet(*feed("dcs", d)), d.outliers);  // dcs alone rejects them
  request(d, "none", "none");
  const auto forced = feed("dcs", d);
  EXPECT_TRUE(forced->rejected().empty());
  EXPECT_GT(inlierChi2(*forced, d), 2.0 * d.optimum);  // least squares on everything
  for (const auto& [id, w] : forced->decisions()) EXPECT_EQ(w, 1.0) << id;
}

TEST(PerFactorRobust, TheSolversOwnNameAndWholeGraphSchemesMeanTheSolversHandling) {
  auto b = std::make_unique<PerFactorRobustBackend>(makeBackend("isam2"));
  Data d = intelWithOutliers();
  const FactorPtr closure =
      *std::find_if(d.problem.graph.factors().begin(), d.problem.graph.factors().end(),
                    [](const FactorPtr& f) { return isUncertain(f->role()); });
  auto f = std::const_pointer_cast<Factor>(closure);
  for (const char* v : {"", "isam2", "risam", "gnc-tls"}) {
    f->setRobustRequest({v, 0.0});
    EXPECT_FALSE(b->handlesHere(*f)) << v;
  }
  for (const char* v : {"none", "huber", "cauchy", "gm", "dcs", "sc", "mm"}) {
    f->setRobustRequest({v, 0.0});
    EXPECT_TRUE(b->handlesHere(*f)) << v;
  }
  // Odometry and priors are always the solver's (trusted).
  for (const auto& g : d.problem.graph.factors())
    if (!isUncertain(g->role())) {
      std::const_pointer_cast<Factor>(g)->setRobustRequest({"dcs", 0.0});
      EXPECT_FALSE(b->handlesHere(*g));
      break;
    }
}

TEST(PerFactorRobust, RemovingAHandledFactorForgetsItsDecision) {
  const Data d = intelWithOutliers();
  request(d, "dcs");
  auto b = feed("isam2", d);
  const FactorId gone = *d.outliers.begin();
  BackendUpdate u;
  u.removals = {gone};
  b->update(u);
  for (const auto& [id, w] : b->decisions()) EXPECT_NE(id, gone);
  EXPECT_FALSE(rejectedSet(*b).count(gone));
  EXPECT_EQ(b->graph().size(), d.problem.graph.size() - 1);
}

// Per-factor kernels under the batch solvers, fed as the server is fed by a front-end that
// sends many poses at once: each batch carries whole steps of the incremental schedule until
// it holds at least edgesPerBatch factors, its new poses placed by odometry from the
// estimate. Checks that each update's moved list names every variable that moved.
struct BatchFeed {
  int updates = 0;
  bool movedReported = true;  // every variable that moved was in its update's moved list
};

BatchFeed feedInBatches(Backend& b, const PoseGraphProblem& p, int edgesPerBatch) {
  BatchFeed feed;
  BackendUpdate u;
  auto send = [&] {
    if (!predictMissingValues(u.factors, b.estimate(), u.initial))
      throw std::runtime_error("batch not reachable by odometry");
    const Values before = b.estimate();
    const std::vector<Key> moved = b.update(u).moved;
    const std::set<Key> reported(moved.begin(), moved.end());
    const Values& x = b.estimate();
    for (int s = 0; s < x.size(); ++s) {
      const int old = before.slot(x.key(s));
      bool m = old < 0;
      for (int i = 0; !m && i < kValueStride; ++i)
        m = std::abs(x.data(s)[i] - before.data(old)[i]) > 1e-4;
      if (m && !reported.count(x.key(s))) feed.movedReported = false;
    }
    ++feed.updates;
    u = BackendUpdate();
  };
  const std::vector<IncrementalStep> steps = incrementalSchedule(p);
  for (size_t i = 0; i < steps.size(); ++i) {
    if (i == 0) u.initial.insertFrom(p.initial, p.initial.slot(steps[i].pose));
    for (int f : steps[i].factors) u.factors.push_back(p.graph[f]);
    if (static_cast<int>(u.factors.size()) >= edgesPerBatch) send();
  }
  if (!u.factors.empty()) send();
  return feed;
}

// intel's first 300 poses, optionally with wrong closures; every closure asks for `kernel`.
struct Intel300 {
  PoseGraphProblem problem;
  std::set<FactorId> outliers;
  int closures = 0;
  double optimum = 0.0;  // chi2 of the outlier-free optimum (0.827)
};

Intel300 intel300(const std::string& kernel, const tools::OutlierOptions* wrong = nullptr) {
  const io::Dataset clean = test::loadPrefix("intel.g2o:300");
  Intel300 d;
  auto lm = makeBackend("lm");
  lm->update(wholeProblemUpdate(buildProblem(clean)));
  d.optimum = lm->chi2();
  if (wrong) {
    const tools::OutlierResult r = tools::addOutliers(clean, *wrong);
    d.problem = buildProblem(r.graph);
    d.outliers.insert(r.outliers.begin(), r.outliers.end());
  } else {
    d.problem = buildProblem(clean);
  }
  for (const auto& f : d.problem.graph.factors())
    if (isUncertain(f->role())) {
      std::const_pointer_cast<Factor>(f)->setRobustRequest({kernel, 0.0});
      ++d.closures;
    }
  return d;
}

// The server's solver set-up: no linear initialization, new poses from odometry.
std::unique_ptr<PerFactorRobustBackend> serverSolver(const std::string& name) {
  BackendOptions o;
  o.linearInitialization = false;
  return std::make_unique<PerFactorRobustBackend>(makeBackend(name, o));
}

TEST(HeldKernelFactor, WeighsByTheHeldWeightUntilRefreshed) {
  auto inner = std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(1), SE2(1, 0, 0),
                                                  Eigen::Matrix3d::Identity());
  const auto held = HeldKernelFactor::make(inner, KernelType::DCS);
  Values x;
  x.insert(poseKey(0), SE2(0, 0, 0));
  x.insert(poseKey(1), SE2(4, 0, 0));  // χ² = 9: DCS weight (2/10)² = 0.04
  EXPECT_EQ(held->heldWeight(), 1.0);
  EXPECT_DOUBLE_EQ(held->chi2(x), 9.0);
  EXPECT_NEAR(held->holdWeightAt(x), 0.96, 1e-12);
  EXPECT_NEAR(held->chi2(x), 0.04 * 9.0, 1e-12);
  // Moved nearer, it keeps its weight (a batch solver's steps are judged by a fixed weighted
  // least-squares cost) while weightAt follows the point.
  x.set(x.slot(poseKey(1)), SE2(2, 0, 0));  // χ² = 1: DCS weight 1
  EXPECT_NEAR(held->chi2(x), 0.04, 1e-12);
  EXPECT_EQ(held->weightAt(x), 1.0);
  EXPECT_NEAR(held->holdWeightAt(x), 0.96, 1e-12);
  EXPECT_DOUBLE_EQ(held->chi2(x), 1.0);
}

// At the odometry's prediction intel's 25 closures (poses 17–45 to 270–299, all in the second
// 200-edge batch) sit at χ² 42–61, DCS weight ≈ 0.0015. Weighed at every trial point, each
// closure's w·χ² falls as it is pulled apart, so lm, gn and dogleg refused every step that
// brought them in and stopped at χ² 1261.67, all 25 rejected; isam2 (steps taken at the
// linearization point's weights) is exact.
TEST(PerFactorRobust, BatchSolversFedLargeBatchesReachTheOptimumWithKernelRequests) {
  const Intel300 d = intel300("dcs");
  ASSERT_EQ(d.closures, 25);
  ASSERT_NEAR(d.optimum, 0.827, 1e-3);
  for (const char* solver : {"lm", "gn", "dogleg", "gnc-tls", "isam2"}) {
    SCOPED_TRACE(solver);
    const auto b = serverSolver(solver);
    const BatchFeed feed = feedInBatches(*b, d.problem, 200);
    EXPECT_EQ(feed.updates, 2);
    EXPECT_TRUE(feed.movedReported);
    // The batch solvers settle their held weights within each update.
    if (std::string(solver) != "isam2") EXPECT_LT(b->chi2(), 1.0001 * d.optimum);
    b->optimize();
    EXPECT_LT(b->chi2(), 1.0001 * d.optimum);
    EXPECT_TRUE(b->rejected().empty());
    int accepted = 0;
    for (const auto& [id, w] : b->decisions()) accepted += w >= 0.99;
    EXPECT_EQ(accepted, d.closures);
  }
}

TEST(PerFactorRobust, BatchSolversFedLargeBatchesStillRejectWrongClosures) {
  for (tools::OutlierMode mode : {tools::OutlierMode::Random, tools::OutlierMode::Group}) {
    tools::OutlierOptions o;
    o.count = 10;
    o.mode = mode;
    o.groupSize = 5;
    o.seed = 2;
    const Intel300 d = intel300("dcs", &o);
    for (const char* solver : {"lm", "gn", "dogleg"}) {
      SCOPED_TRACE(std::string(solver) + " " + tools::outlierModeName(mode));
      const auto b = serverSolver(solver);
      feedInBatches(*b, d.problem, 200);
      EXPECT_EQ(rejectedSet(*b), d.outliers);
      double inliers = 0.0;
      for (const auto& f : d.problem.graph.factors())
        if (!d.outliers.count(f->id())) inliers += f->chi2(b->estimate());
      EXPECT_LT(inliers, 1.001 * d.optimum);
    }
  }
}

}  // namespace
}  // namespace loopd
