// The multi-hypothesis backend: on real 2D and 3D data with ambiguous loop closures (and on
// Victoria Park with ambiguous landmark associations) the best hypothesis takes the true
// alternative and lands on the outlier-free optimum; null hypotheses, the limit K, branching
// independence and validation on small graphs.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "robust/ambiguous_choice.h"
#include "robust/backend_registry.h"
#include "robust/mh_backend.h"
#include "solvers/factors/between_factor_se2.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/problem/pose_graph_problem.h"
#include "tools/loopd-eval/trajectory_metrics.h"
#include "tools/loopd-outliers/ambiguous_generator.h"
#include "tools/loopd-solve/online_run.h"

namespace loopd {
namespace {

const std::string kDatasets = LOOPD_DATASETS_DIR;

// The outlier-free optimum as loopd-solve --incremental reaches it.
double optimumChi2(const io::Dataset& clean) {
  const PoseGraphProblem p = buildProblem(clean);
  auto isam2 = makeBackend("isam2");
  tools::runOnline(*isam2, p, /*quiet=*/true);
  return isam2->chi2();
}

struct AmbiguousRun {
  int groups = 0;
  int correct = 0;
  double inlierChi2 = 0.0;
  double optimum = 0.0;
};

// Makes `count` measurements of the dataset ambiguous, runs `solver` online as loopd-solve
// --incremental does, and scores the choices and the estimate over the true edges.
AmbiguousRun runAmbiguous(const std::string& file, const tools::AmbiguousOptions& opt,
                          const std::string& solver, int maxHypotheses = 10) {
  const io::Dataset clean = io::readDataset(kDatasets + "/" + file);
  const tools::AmbiguousResult amb = tools::makeAmbiguous(clean, opt);
  const PoseGraphProblem p = buildProblem(amb.graph);
  EXPECT_EQ(static_cast<int>(p.ambiguous.size()), opt.count);
  BackendOptions bo;
  bo.maxHypotheses = maxHypotheses;
  auto backend = makeBackend(solver, bo);
  tools::runOnline(*backend, p, /*quiet=*/true);

  const std::vector<int> chosen = chosenAlternatives(*backend, ambiguousFactors(p));
  AmbiguousRun r;
  r.groups = static_cast<int>(chosen.size());
  for (size_t g = 0; g < chosen.size(); ++g) r.correct += chosen[g] == amb.trueChoice[g];
  io::Dataset estimate = amb.graph;
  storeEstimate(backend->estimate(), estimate);
  std::vector<std::int64_t> decoys(amb.decoys.begin(), amb.decoys.end());
  r.inlierChi2 = tools::inlierChi2(amb.graph, estimate, decoys);
  r.optimum = optimumChi2(clean);
  return r;
}

TEST(MhBackend, ManhattanAmbiguousLoopClosuresPickTheTrueAlternative) {
  tools::AmbiguousOptions opt;
  opt.count = 60;
  opt.null = true;
  opt.decoys = tools::DecoyMode::Mixed;
  opt.seed = 7;
  const AmbiguousRun r = runAmbiguous("manhattan.g2o", opt, "mh");
  EXPECT_EQ(r.correct, r.groups);
  EXPECT_NEAR(r.inlierChi2, r.optimum, 1e-3 * r.optimum);
}

TEST(MhBackend, Sphere2500AmbiguousLoopClosuresPickTheTrueAlternative) {
  tools::AmbiguousOptions opt;
  opt.count = 20;
  opt.null = true;
  opt.decoys = tools::DecoyMode::Target;
  opt.seed = 3;
  const AmbiguousRun r = runAmbiguous("sphere2500.g2o", opt, "mh");
  EXPECT_EQ(r.correct, r.groups);
  EXPECT_NEAR(r.inlierChi2, r.optimum, 1e-3 * r.optimum);
}

TEST(MhBackend, VictoriaParkAmbiguousLandmarkAssociations) {
  tools::AmbiguousOptions opt;
  opt.count = 40;
  opt.landmarks = true;
  opt.decoys = tools::DecoyMode::Target;
  opt.seed = 5;
  const AmbiguousRun r = runAmbiguous("victoria_park.txt", opt, "mh");
  EXPECT_EQ(r.correct, r.groups);
  EXPECT_NEAR(r.inlierChi2, r.optimum, 1e-3 * r.optimum);
}

TEST(MhBackend, WithoutHypothesesDecoysMislead) {
  // The same data through plain isam2 (decoys flattened into ordinary loop closures) is far
  // from the optimum: what makes the test above mean something.
  tools::AmbiguousOptions opt;
  opt.count = 20;
  opt.seed = 7;
  const AmbiguousRun r = runAmbiguous("manhattan.g2o", opt, "isam2");
  EXPECT_GT(r.inlierChi2, 2.0 * r.optimum);
}

// --- small graphs: a square walk of 8 poses (1 m steps, left turns after 2), its true loop
// closure from the last pose back to pose 0, and decoys.
struct Square {
  std::vector<FactorPtr> odometry;
  Values initial;
  SE2 truth[9];
};

Square square() {
  Square s;
  const Eigen::Matrix3d info = Eigen::Vector3d(100, 100, 400).asDiagonal();
  SE2 x(0, 0, 0);
  s.truth[0] = x;
  for (int i = 1; i <= 8; ++i) {
    const SE2 step(1.0, 0.0, i % 2 == 0 ? M_PI / 2 : 0.0);
    x = x * step;
    s.truth[i] = x;
    auto f = std::make_shared<BetweenFactorSE2>(poseKey(i - 1), poseKey(i), step, info,
                                                FactorRole::Odometry);
    f->setId(i);
    s.odometry.push_back(f);
  }
  return s;
}

FactorPtr closure(FactorId id, int a, int b, const SE2& m) {
  auto f = std::make_shared<BetweenFactorSE2>(
      poseKey(a), poseKey(b), m, Eigen::Matrix3d::Identity() * 100.0, FactorRole::LoopClosure);
  f->setId(id);
  return f;
}

std::unique_ptr<MhBackend> squareBackend(int k = 10) {
  BackendOptions o;
  o.maxHypotheses = k;
  auto mh = std::make_unique<MhBackend>(o, MhOptions{});
  const Square s = square();
  BackendUpdate u;
  u.factors = s.odometry;
  u.initial.insert(poseKey(0), SE2());
  mh->update(u);
  return mh;
}

SE2 relative(int a, int b) {
  const Square s = square();
  return s.truth[a].inverse() * s.truth[b];
}

TEST(MhBackend, NullWinsWhenEveryAlternativeIsWrong) {
  auto mh = squareBackend();
  AmbiguousFactor a;
  a.id = 1;
  a.nullHypothesis = true;
  a.alternatives = {closure(100, 8, 0, SE2(3, 1, 1)), closure(101, 8, 1, SE2(-2, 2, -1))};
  BackendUpdate u;
  u.ambiguous.push_back(a);
  mh->update(u);
  EXPECT_EQ(mh->chosenAlternative(1), -1);
  EXPECT_EQ(mh->rejected().size(), 2u);
}

TEST(MhBackend, TrueAlternativeWinsAndTheOthersAreRejected) {
  auto mh = squareBackend();
  AmbiguousFactor a;
  a.id = 5;
  a.nullHypothesis = true;
  a.alternatives = {closure(100, 8, 3, relative(8, 0)), closure(101, 8, 0, relative(8, 0)),
                    closure(102, 8, 0, SE2(0.5, -0.5, 0.3))};
  BackendUpdate u;
  u.ambiguous.push_back(a);
  mh->update(u);
  EXPECT_EQ(mh->chosenAlternative(5), 1);
  EXPECT_EQ(mh->rejected(), (std::vector<FactorId>{100, 102}));
  EXPECT_LT(mh->chi2(), 1e-12);
  EXPECT_FALSE(mh->chosenAlternative(6).has_value());
}

TEST(MhBackend, WithoutNullTheLeastImplausibleAlternativeIsTaken) {
  auto mh = squareBackend();
  AmbiguousFactor a;
  a.id = 2;
  a.alternatives = {closure(100, 8, 0, SE2(5, 5, 2)), closure(101, 8, 0, SE2(0.3, 0.1, 0.05))};
  BackendUpdate u;
  u.ambiguous.push_back(a);
  mh->update(u);
  EXPECT_EQ(mh->chosenAlternative(2), 1);
}

TEST(MhBackend, UndecidedAlternativesStayAliveUpToK) {
  // Two alternatives that fit equally well now: both live until data decide; K = 1 keeps one.
  for (int k : {1, 10}) {
    auto mh = squareBackend(k);
    AmbiguousFactor a;
    a.id = 3;
    const SE2 m = relative(8, 0);
    a.alternatives = {closure(100, 8, 0, m), closure(101, 8, 0, m * SE2(0.01, 0.0, 0.0))};
    BackendUpdate u;
    u.ambiguous.push_back(a);
    mh->update(u);
    EXPECT_EQ(mh->liveHypotheses(), std::min(k, 2)) << "K = " << k;
    for (const auto& h : mh->hypotheses(10)) EXPECT_EQ(h.choices.size(), 1u);
  }
}

TEST(MhBackend, LaterDataDecideBetweenLiveHypotheses) {
  // The first odometry step is measured 0.2 m long, so at first the wrong alternative (what
  // dead reckoning predicts) fits better than the true one; both stay alive. A later, tight
  // closure 2 → 0 exposes the odometry error, and the true alternative takes over.
  Square s = square();
  auto longStep = std::make_shared<BetweenFactorSE2>(poseKey(0), poseKey(1), SE2(1.2, 0, 0),
                                                     Eigen::Vector3d(100, 100, 400).asDiagonal(),
                                                     FactorRole::Odometry);
  longStep->setId(1);
  s.odometry[0] = longStep;
  MhBackend mh(BackendOptions{}, MhOptions{});
  BackendUpdate u;
  u.factors = s.odometry;
  u.initial.insert(poseKey(0), SE2());
  mh.update(u);
  const SE2 deadReckoned = mh.estimate().se2(mh.estimate().slot(poseKey(8))).inverse() *
                           mh.estimate().se2(mh.estimate().slot(poseKey(0)));
  AmbiguousFactor a;
  a.id = 4;
  a.alternatives = {closure(100, 8, 0, deadReckoned), closure(101, 8, 0, relative(8, 0))};
  BackendUpdate amb;
  amb.ambiguous.push_back(a);
  mh.update(amb);
  ASSERT_EQ(mh.liveHypotheses(), 2);
  EXPECT_EQ(mh.chosenAlternative(4), 0);
  auto tight = std::make_shared<BetweenFactorSE2>(poseKey(2), poseKey(0), relative(2, 0),
                                                  Eigen::Matrix3d::Identity() * 1e4,
                                                  FactorRole::LoopClosure);
  tight->setId(200);
  BackendUpdate later;
  later.factors.push_back(tight);
  mh.update(later);
  EXPECT_EQ(mh.chosenAlternative(4), 1);
  mh.optimize();
  EXPECT_EQ(mh.chosenAlternative(4), 1);
}

TEST(MhBackend, BranchesAreIndependentCopies) {
  auto mh = squareBackend();
  AmbiguousFactor a;
  a.id = 3;
  const SE2 m = relative(8, 0);
  a.alternatives = {closure(100, 8, 0, m), closure(101, 8, 0, m * SE2(0.05, 0.0, 0.0))};
  BackendUpdate u;
  u.ambiguous.push_back(a);
  mh->update(u);
  const auto hs = mh->hypotheses(2);
  ASSERT_EQ(hs.size(), 2u);
  EXPECT_NE(hs[0].choices[0], hs[1].choices[0]);
  const Values& x0 = *hs[0].estimate;
  const Values& x1 = *hs[1].estimate;
  const double dx = x0.se2(x0.slot(poseKey(4))).x - x1.se2(x1.slot(poseKey(4))).x;
  EXPECT_GT(std::abs(dx), 1e-4);  // each took its own closure
}

TEST(MhBackend, LiveHypothesesShareTheCliquesTheirChoiceDoesNotTouch) {
  // A 400-pose square walk, then an ambiguous closure among the last poses whose two
  // alternatives fit alike: two hypotheses live, and everything below the closure's path to
  // the root is one set of cliques for both.
  BackendOptions o;
  auto mh = std::make_unique<MhBackend>(o, MhOptions{});
  const Eigen::Matrix3d info = Eigen::Vector3d(100, 100, 400).asDiagonal();
  std::vector<SE2> truth = {SE2()};
  for (int i = 1; i < 400; ++i) {
    const SE2 step(1.0, 0.0, i % 10 == 0 ? M_PI / 2 : 0.0);
    truth.push_back(truth.back() * step);
    BackendUpdate u;
    auto f = std::make_shared<BetweenFactorSE2>(poseKey(i - 1), poseKey(i), step, info,
                                                FactorRole::Odometry);
    f->setId(i);
    u.factors.push_back(f);
    if (i == 1) u.initial.insert(poseKey(0), SE2());
    mh->update(u);
  }
  AmbiguousFactor a;
  a.id = 1000;
  const SE2 m = truth[399].inverse() * truth[395];
  a.alternatives = {closure(1001, 399, 395, m), closure(1002, 399, 395, m * SE2(0.01, 0, 0))};
  BackendUpdate u;
  u.ambiguous.push_back(a);
  mh->update(u);
  ASSERT_EQ(mh->liveHypotheses(), 2);
  const MhBackend::Storage s = mh->cliqueStorage();
  EXPECT_LT(s.sharedBytes, 0.6 * s.unsharedBytes) << s.sharedBytes << " of " << s.unsharedBytes;
  EXPECT_GT(s.sharedBytes, 0.5 * s.unsharedBytes);  // the closure's own cliques differ
}

TEST(MhBackend, InvalidUpdatesAreRefusedWhole) {
  auto mh = squareBackend();
  const int factorsBefore = mh->graph().size();
  AmbiguousFactor unknown;
  unknown.id = 1;
  unknown.alternatives = {closure(100, 8, 0, SE2()), closure(101, 8, 42, SE2())};
  BackendUpdate u;
  u.factors.push_back(closure(50, 8, 2, relative(8, 2)));
  u.ambiguous.push_back(unknown);
  EXPECT_THROW(mh->update(u), std::invalid_argument);
  EXPECT_EQ(mh->graph().size(), factorsBefore);  // the plain factor did not go in either

  AmbiguousFactor good;
  good.id = 1;
  good.nullHypothesis = true;
  good.alternatives = {closure(100, 8, 0, relative(8, 0))};
  BackendUpdate ok;
  ok.ambiguous.push_back(good);
  mh->update(ok);
  BackendUpdate again;
  good.alternatives = {closure(110, 8, 0, relative(8, 0))};
  again.ambiguous.push_back(good);  // same measurement id
  EXPECT_THROW(mh->update(again), std::invalid_argument);
  BackendUpdate removeAlternative;
  removeAlternative.removals = {100};
  EXPECT_THROW(mh->update(removeAlternative), std::invalid_argument);
  AmbiguousFactor single;
  single.id = 9;
  single.alternatives = {closure(120, 8, 0, relative(8, 0))};
  BackendUpdate one;
  one.ambiguous.push_back(single);
  EXPECT_THROW(mh->update(one), std::invalid_argument);
}

TEST(MhBackend, OtherVariantsRefuseUnflattenedAmbiguity) {
  auto isam2 = makeBackend("isam2");
  BackendUpdate u;
  u.initial.insert(poseKey(0), SE2());
  u.initial.insert(poseKey(1), SE2(1, 0, 0));
  u.factors.push_back(closure(1, 0, 1, SE2(1, 0, 0)));
  AmbiguousFactor a;
  a.id = 1;
  a.alternatives = {closure(2, 0, 1, SE2(1, 0, 0)), closure(3, 0, 1, SE2(2, 0, 0))};
  u.ambiguous.push_back(a);
  EXPECT_THROW(isam2->update(u), std::invalid_argument);
  flattenAmbiguous(u);
  EXPECT_EQ(u.factors.size(), 3u);
  EXPECT_NO_THROW(isam2->update(u));
}

}  // namespace
}  // namespace loopd
