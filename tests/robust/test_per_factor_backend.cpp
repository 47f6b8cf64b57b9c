// The robust handling a sender asks for per factor (the wire's `robust`), applied around any
// solver: a kernel, sc or mm on chosen closures, "none" to force trust, the solver's own
// handling otherwise.
#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <string>

#include "robust/backend_registry.h"
#include "robust/per_factor_backend.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/problem/pose_graph_problem.h"
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

}  // namespace
}  // namespace loopd
