// Every robust variant on a real dataset with synthetic wrong loop closures from
// loopd-outliers' generator: rejections (precision/recall) and the chi2 over the true edges
// against the outlier-free optimum; with no outliers, every variant keeps (nearly)
// everything and reaches the plain optimum.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <string>

#include "robust/backend_registry.h"
#include "robust/gnc_backend.h"
#include "robust/robust_factors.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/problem/pose_graph_problem.h"
#include "tests/robust/dataset_prefix.h"
#include "tools/loopd-eval/trajectory_metrics.h"
#include "tools/loopd-outliers/outlier_generator.h"
#include "tools/loopd-solve/online_run.h"

namespace loopd {
namespace {

using tools::OutlierMode;

struct RunResult {
  double inlierChi2 = 0.0;
  tools::DecisionScores scores;
  int rejected = 0;
  double seconds = 0.0;
};

// Feeds the problem pose by pose (as loopd-solve --incremental does), or all at once.
std::unique_ptr<Backend> solve(const std::string& variant, const PoseGraphProblem& p,
                               bool incremental) {
  auto b = makeBackend(variant);
  if (incremental)
    tools::runOnline(*b, p, /*quiet=*/true);
  else
    b->update(wholeProblemUpdate(p));
  return b;
}

bool isIncremental(const std::string& v) { return v != "gnc-gm" && v != "gnc-tls"; }

RunResult score(const Backend& b, const PoseGraphProblem& p, const tools::OutlierResult& data);

RunResult run(const std::string& variant, const tools::OutlierResult& data) {
  const PoseGraphProblem p = buildProblem(data.graph);
  const auto t0 = std::chrono::steady_clock::now();
  auto b = solve(variant, p, isIncremental(variant));
  RunResult r = score(*b, p, data);
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

RunResult score(const Backend& b0, const PoseGraphProblem& p, const tools::OutlierResult& data) {
  const Backend* b = &b0;
  RunResult r;
  for (const auto& f : p.graph.factors())
    if (static_cast<int>(f->id()) < data.inlierEdges) r.inlierChi2 += f->chi2(b->estimate());
  std::vector<std::int64_t> rejected, truth(data.outliers.begin(), data.outliers.end());
  for (FactorId id : b->rejected()) rejected.push_back(static_cast<std::int64_t>(id));
  r.rejected = static_cast<int>(rejected.size());
  r.scores = tools::scoreRejections(rejected, truth);
  return r;
}

struct Reference {
  io::Dataset dataset;
  double optimumChi2 = 0.0;
};

using test::loadPrefix;

const Reference& reference(const std::string& file) {
  static std::map<std::string, Reference> cache;
  auto it = cache.find(file);
  if (it != cache.end()) return it->second;
  Reference r;
  r.dataset = loadPrefix(file);
  const PoseGraphProblem p = buildProblem(r.dataset);
  auto b = solve("lm", p, false);
  r.optimumChi2 = b->chi2();
  return cache.emplace(file, std::move(r)).first->second;
}

struct Case {
  std::string variant;
  std::string dataset;
  OutlierMode mode;
  int count;
  // Expectations (what holds for this variant and scenario).
  double minRecall, minPrecision, chi2Tolerance;  // relative, over the true edges
};

std::string caseName(const Case& c) {
  std::string n =
      c.variant + "_" + c.dataset.substr(0, c.dataset.find('.')) +
      (c.dataset.find(':') != std::string::npos ? c.dataset.substr(c.dataset.find(':') + 1) : "") +
      "_" + tools::outlierModeName(c.mode) + std::to_string(c.count);
  for (char& ch : n)
    if (!isalnum(static_cast<unsigned char>(ch))) ch = '_';
  return n;
}

class RobustVariants : public ::testing::TestWithParam<Case> {};

TEST_P(RobustVariants, RejectsOutliersAndReachesTheOptimum) {
  const Case& c = GetParam();
  const Reference& ref = reference(c.dataset);
  tools::OutlierOptions o;
  o.count = c.count;
  o.mode = c.mode;
  o.groupSize = 5;
  o.seed = 42;
  const tools::OutlierResult data = tools::addOutliers(ref.dataset, o);
  const RunResult r = run(c.variant, data);
  const double rel = (r.inlierChi2 - ref.optimumChi2) / ref.optimumChi2;
  std::printf(
      "[robust] %-8s %-16s %-7s %3d  recall %.3f precision %.3f rejected %3d  "
      "chi2(true) %.6g vs %.6g (%+.4f%%)  %.2f s\n",
      c.variant.c_str(), c.dataset.c_str(), tools::outlierModeName(c.mode), c.count,
      r.scores.recall, r.scores.precision, r.rejected, r.inlierChi2, ref.optimumChi2, 100 * rel,
      r.seconds);
  EXPECT_GE(r.scores.recall, c.minRecall);
  EXPECT_GE(r.scores.precision, c.minPrecision);
  EXPECT_LE(std::abs(rel), c.chi2Tolerance);
}

// Expectations are what each variant achieves (seed 42, groups of 5); kNone skips a bound.
// Known failures are kept visible in the expectations rather than hidden:
//  - groups of mutually consistent outliers can defeat riSAM (accepted groups bend the map;
//    intel's and parking-garage's prefixes no longer since its gate tightens), while the
//    incremental dcs/sc/mm reject each member as it arrives; the batch GNCs handle them
//    since they also run from the odometry start (GncOptions::odometryStart);
//  - on smallGrid3D, whose edges carry their true noise (χ² ≈ dof per edge), DCS and SC with
//    Φ = 1 / σ = 1 switch off almost every loop closure, and χ² tests reject a few true ones.
constexpr double kNone = 1e300;

std::vector<Case> cases() {
  const char* intel = "intel.g2o:600";
  const char* grid = "smallGrid3D.g2o";
  const auto R = OutlierMode::Random, L = OutlierMode::Local, G = OutlierMode::Group;
  return {
      // zero outliers: nothing rejected, the plain optimum
      {"gnc-tls", intel, R, 0, 1, 1, 0.01},
      {"gnc-gm", intel, R, 0, 1, 1, 0.01},
      {"risam", intel, R, 0, 1, 1, 0.01},
      {"dcs", intel, R, 0, 1, 1, 0.01},
      {"sc", intel, R, 0, 1, 1, 0.01},
      {"mm", intel, R, 0, 1, 1, 0.01},
      {"huber", intel, R, 0, 1, 1, 0.01},
      {"cauchy", intel, R, 0, 1, 1, 0.01},
      {"gm", intel, R, 0, 1, 1, 0.01},
      // 30 random / local / grouped outliers
      {"gnc-tls", intel, R, 30, 0.95, 0.95, 0.01},
      {"gnc-tls", intel, L, 30, 0.95, 0.95, 0.01},
      {"gnc-tls", intel, G, 30, 0.95, 0.95, 0.01},
      {"gnc-gm", intel, R, 30, 0.85, 0.95, kNone},
      {"gnc-gm", intel, L, 30, 0.95, 0.95, kNone},
      {"gnc-gm", intel, G, 30, 0.95, 0.95, kNone},
      {"risam", intel, R, 30, 0.95, 0.95, 0.01},
      {"risam", intel, L, 30, 0.95, 0.95, 0.01},
      // riSAM: one group of 5 got in (it bent the map in the convex phase) until intel's
      // under-confident information tightened its gate (RisamOptions::tighten).
      {"risam", intel, G, 30, 0.95, 0.95, 0.01},
      {"dcs", intel, R, 30, 0.95, 0.95, 0.01},
      {"dcs", intel, L, 30, 0.95, 0.95, 0.01},
      {"dcs", intel, G, 30, 0.95, 0.95, 0.01},
      {"sc", intel, R, 30, 0.95, 0.95, 0.01},
      {"sc", intel, L, 30, 0.95, 0.95, 0.01},
      {"sc", intel, G, 30, 0.95, 0.95, 0.01},
      {"mm", intel, R, 30, 0.95, 0.95, 0.01},
      {"mm", intel, L, 30, 0.95, 0.95, kNone},
      {"mm", intel, G, 30, 0.95, 0.95, 0.01},
      // the whole of intel, random outliers, for the variants that handle them
      {"gnc-tls", "intel.g2o", R, 30, 0.95, 0.95, 0.01},
      {"dcs", "intel.g2o", R, 30, 0.95, 0.95, 0.01},
      {"risam", "intel.g2o", R, 30, 0.95, 0.95, 0.01},
      // manhattan's stiff closures (information 2e7) and heavy tail: riSAM used to drop true
      // ones online (SIG weight taken at iSAM2's lagging linearization point; GM-weighted
      // final estimate) — now none, and the plain optimum
      {"risam", "manhattan.g2o:1500", R, 0, 1, 1, 0.01},
      {"risam", "manhattan.g2o:1500", R, 50, 1, 1, 0.01},
      // parking-garage's under-confident information (true closures at 1e-5 of χ²_dim): wrong
      // closures bent the flexible map until they fit the χ²_dim defaults (recall 0 random,
      // 0.27 group); the tightened noise-aware gate (RisamOptions::tighten) rejects them
      {"risam", "parking-garage.g2o:800", R, 0, 1, 1, 0.01},
      {"risam", "parking-garage.g2o:800", R, 30, 0.95, 0.95, 0.01},
      {"risam", "parking-garage.g2o:800", G, 30, 0.95, 0.95, 0.01},
      // 3D
      {"gnc-tls", grid, R, 20, 0.95, 0.85, 0.10},
      {"gnc-gm", grid, R, 20, 0.95, 0.35, 0.06},
      {"risam", grid, R, 20, 0.95, 0.6, 0.2},
      {"mm", grid, R, 20, 0.95, 0.95, 0.05},
      {"dcs", grid, R, 20, 0.95, 0.0, kNone},
      {"sc", grid, R, 20, 0.95, 0.0, kNone},
  };
}

INSTANTIATE_TEST_SUITE_P(All, RobustVariants, ::testing::ValuesIn(cases()),
                         [](const auto& info) { return caseName(info.param); });

// --- Noise-aware gates --------------------------------------------------------------------

TEST(TailGate, MedianAndTailOfNormalizedChi2) {
  // 1000 values: 0.01·i/1000 for the bulk, a heavy tail in the top 10%.
  std::vector<double> q;
  for (int i = 0; i < 900; ++i) q.push_back(1.0 * i / 900);
  for (int i = 0; i < 100; ++i) q.push_back(1.0 + 0.1 * i);
  const TailGate t = tailGate(q, 3.0, 1e9);
  EXPECT_NEAR(t.scale, 500.0 / 900, 1e-9);       // q[500]
  const double q90 = 1.0, q99 = 1.0 + 0.1 * 90;  // q[900], q[990]
  EXPECT_NEAR(t.gate, q99 * std::pow(q99 / q90, 3.0), 1e-9);
  EXPECT_NEAR(tailGate(q, 3.0, 10.0).gate, 10.0 * t.scale, 1e-9);  // capped by the median
  EXPECT_NEAR(tailGate(q, 3.0, 10.0).tail, q99 * std::pow(q99 / q90, 3.0), 1e-9);  // uncapped
  EXPECT_EQ(tailGate({1, 2, 3}, 3.0, 100.0).gate, 0.0);                            // too few values
  // More than half exact fits (noise-free closures): the median cap is 0, the tail is not,
  // which is why the re-check at the tail reads `tail`.
  std::vector<double> exact(600, 0.0);
  for (int i = 0; i < 400; ++i) exact.push_back(0.01 * (i + 1));
  EXPECT_EQ(tailGate(exact, 3.0, 100.0).gate, 0.0);
  EXPECT_GT(tailGate(exact, 3.0, 100.0).tail, 0.0);
}

// The issue protocol's outliers on a reference dataset (groups of 10).
tools::OutlierResult protocolOutliers(const Reference& ref, int count, OutlierMode mode,
                                      unsigned seed = 1) {
  tools::OutlierOptions o;
  o.count = count;
  o.mode = mode;
  o.groupSize = 10;
  o.seed = seed;
  return tools::addOutliers(ref.dataset, o);
}

// One GNC run with options g (gnc-tls unless g.loss says otherwise), printed with `label` and
// its stop reason.
RunResult solveGnc(const GncOptions& g, const tools::OutlierResult& data, const Reference& ref,
                   const std::string& label) {
  const PoseGraphProblem p = buildProblem(data.graph);
  GncBackend b(BackendOptions{}, g);
  b.update(wholeProblemUpdate(p));
  RunResult r = score(b, p, data);
  std::printf("[robust] %s %s: recall %.3f precision %.3f chi2(true) %.6g vs %.6g (%s)\n",
              b.name().c_str(), label.c_str(), r.scores.recall, r.scores.precision, r.inlierChi2,
              ref.optimumChi2, b.summary().stopReason.c_str());
  return r;
}

// Every outlier rejected, nothing true, at the outlier-free optimum.
void expectExact(const RunResult& r, const Reference& ref) {
  EXPECT_EQ(r.scores.recall, 1.0);
  EXPECT_EQ(r.scores.precision, 1.0);
  EXPECT_LE(std::abs(r.inlierChi2 - ref.optimumChi2), 1e-3 * ref.optimumChi2);
}

// The two halves of a GNC test: the GNC with `part` switched off, then on (part(g, on) sets
// the options), each labelled "`what` 0" / "`what` 1".
struct OffAndOn {
  RunResult off, on;
};
OffAndOn offAndOn(const tools::OutlierResult& data, const Reference& ref, const std::string& what,
                  const std::function<void(GncOptions&, bool)>& part) {
  OffAndOn r;
  for (bool on : {false, true}) {
    GncOptions g;
    part(g, on);
    (on ? r.on : r.off) = solveGnc(g, data, ref, what + (on ? " 1" : " 0"));
  }
  return r;
}

// manhattan's loop closures are heavy-tailed (largest true χ² 31× the median, above
// χ²₃(0.99)): a GNC with the fixed χ²_dim(0.99) threshold lands in a local minimum that drops
// true closures (precision 0.79 on the first 1500 poses with 50 random outliers); the
// noise-aware gate must keep every true closure and reject every outlier. Both halves are
// checked, so the test fails if the data stops exercising the problem.
TEST(NoiseAwareGnc, KeepsManhattansHeavyTailedTrueClosures) {
  const Reference& ref = reference("manhattan.g2o:1500");
  const tools::OutlierResult data = protocolOutliers(ref, 50, OutlierMode::Random);
  const OffAndOn r =
      offAndOn(data, ref, "manhattan:1500 random 50, noise-aware gate", [](GncOptions& g, bool on) {
        if (!on) g.tailExponent = -1.0;  // the gate off
      });
  EXPECT_LT(r.off.scores.precision, 0.95) << "the fixed threshold no longer drops true closures";
  expectExact(r.on, ref);
}

// gnc-gm counted a closure as accepted from weight 0.5, which GM gives at χ² = 0.41·c̄² when
// μ = 1: the gate read from those cut manhattan's true tail, and with 100 wrong closures in
// groups (seed 3) the true closure 4580 went out (its removal gain 29.6 against a gate of 28.4;
// ×3.4 on the true edges). Accepted from 0.25 (χ² ≤ c̄²) and decided 0/1 at the end
// (GncOptions::gmDecidesAtThreshold), it is exact. Both halves are checked.
TEST(GncGmDecisions, ReadTheGateFromEveryClosureWithinTheThreshold) {
  const Reference& ref = reference("manhattan.g2o");
  const tools::OutlierResult data = protocolOutliers(ref, 100, OutlierMode::Group, 3);
  const OffAndOn r =
      offAndOn(data, ref, "manhattan group 100 seed 3, 0/1 decisions", [](GncOptions& g, bool on) {
        g.loss = GncLoss::GemanMcClure;
        g.gmDecidesAtThreshold = on;
      });
  EXPECT_LT(r.off.scores.precision, 1.0) << "the tail edge no longer goes out without it";
  expectExact(r.on, ref);
}

// Groups of mutually consistent outliers bend the all-closures least-squares start on intel
// (100 outliers in groups of 10, seed 1): the plain GNC from there accepts 15 outliers and
// drops 3 true closures (recall 0.85, precision 0.97), a local minimum (truncated cost 990
// against 371 from the odometry start, at the noise-aware gate). The GNC redone from the
// odometry start finds the truth; the cheaper candidate is kept. Both halves are checked.
TEST(GncOdometryStart, EscapesTheMinimumGroupsBendTheStartInto) {
  const Reference& ref = reference("intel.g2o");
  const tools::OutlierResult data = protocolOutliers(ref, 100, OutlierMode::Group);
  const OffAndOn r =
      offAndOn(data, ref, "intel group 100, odometry start", [](GncOptions& g, bool on) {
        g.odometryStart = on;
        // Without the odometry start, the gate's own rerun (candidate B) would step in, and
        // the final checks now get out of that minimum too: the plain GNC from the
        // least-squares start is what is shown failing.
        if (!on) g.tailExponent = -1.0, g.recheckRejected = g.dropClusters = false;
      });
  EXPECT_LT(std::min(r.off.scores.precision, r.off.scores.recall), 0.99)
      << "the least-squares start no longer leads the GNC astray";
  expectExact(r.on, ref);
}

// GncOptions::interrupt (RisamBackend's GNC look under the server) is asked as the GNC works,
// at every iteration of its solves and at every closure of its consistent-set test; "no"
// changes nothing, bit for bit, and "yes" at any of those points throws GncInterrupted.
TEST(GncInterrupt, AskedAsItWorksAndThrowsWhenToldTo) {
  const Reference& ref = reference("intel.g2o");
  const tools::OutlierResult data = protocolOutliers(ref, 100, OutlierMode::Random);
  const PoseGraphProblem p = buildProblem(data.graph);
  GncBackend plain(BackendOptions{}, GncOptions{});
  plain.update(wholeProblemUpdate(p));
  int asked = 0;
  GncOptions g;
  g.interrupt = [&] {
    ++asked;
    return false;
  };
  GncBackend watched(BackendOptions{}, g);
  watched.update(wholeProblemUpdate(p));
  EXPECT_GT(asked, 100);
  EXPECT_EQ(watched.chi2(), plain.chi2());
  EXPECT_EQ(watched.rejected(), plain.rejected());
  for (const int at : {1, asked / 2, asked}) {
    int n = 0;
    g.interrupt = [&] { return ++n == at; };
    GncBackend b(BackendOptions{}, g);
    EXPECT_THROW(b.update(wholeProblemUpdate(p)), GncInterrupted) << "at question " << at;
    EXPECT_EQ(n, at);
  }
}

// The checks' joint marginals (one per group of closures judged) are a long stretch without an
// iteration on large graphs (city10000 with 1000 grouped outliers: 2.8 s): the interrupt is
// asked before each group's too. Without the consistent-set test, the asks beyond the
// iterations are those.
TEST(GncInterrupt, AskedBeforeEachGroupsMarginalInTheChecks) {
  const Reference& ref = reference("intel.g2o");
  const tools::OutlierResult data = protocolOutliers(ref, 100, OutlierMode::Random);
  const PoseGraphProblem p = buildProblem(data.graph);
  int asked = 0, iterations = 0;
  BackendOptions o;
  o.progress = [&](const IterationReport&) { ++iterations; };
  GncOptions g;
  g.consistentStart = false;
  g.interrupt = [&] {
    ++asked;
    return false;
  };
  GncBackend watched(o, g);
  watched.update(wholeProblemUpdate(p));
  EXPECT_GE(asked - iterations, 100) << "the 100 rejected closures' groups, at least";
}

// With 1000 outliers in groups of 10 on intel (seed 1), the groups bend the map from both the
// least-squares and the odometry start (recall 0.95, ATE 11 m, truncated cost 12208 against
// the truth's 11390). The largest pairwise-consistent set of closures (PCM) holds 783 of
// the 785 true closures and 5 wrong ones; deciding from its solution, with the gate its clean
// solution gives, finds the truth. Both halves are checked.
TEST(GncConsistentStart, EscapesWhereConsistentGroupsBendEveryStart) {
  const Reference& ref = reference("intel.g2o");
  const tools::OutlierResult data = protocolOutliers(ref, 1000, OutlierMode::Group);
  const OffAndOn r =
      offAndOn(data, ref, "intel group 1000, consistent start", [](GncOptions& g, bool on) {
        g.consistentStart = on;
        // The final checks would get out too (GncChecks): off, to show the candidate's part.
        if (!on) g.recheckRejected = g.dropClusters = false;
      });
  EXPECT_LT(r.off.scores.recall, 0.99) << "the groups no longer bend both starts";
  expectExact(r.on, ref);
}

// manhattan, 100 outliers in groups of 10, seed 4: from both starts the GNC accepts three of
// one group, which hold the map bent with two true closures pushed out (truncated cost 8067
// against the truth's 7579). The checks (robust/closure_leverage.h) get out: from the
// consistent-set solution a cluster re-check takes back the 590 true closures its own gate
// cut, and on the kept solution removing the group is predicted to gain more than its gates
// cost. Both halves are checked.
TEST(GncChecks, GetOutOfTheMinimumAGroupHoldsTheMapIn) {
  const Reference& ref = reference("manhattan.g2o");
  const tools::OutlierResult data = protocolOutliers(ref, 100, OutlierMode::Group, 4);
  const OffAndOn r =
      offAndOn(data, ref, "manhattan group 100 s4, checks",
               [](GncOptions& g, bool on) { g.recheckRejected = g.dropClusters = on; });
  EXPECT_LT(std::min(r.off.scores.recall, r.off.scores.precision), 0.99)
      << "the group no longer holds the map bent";
  expectExact(r.on, ref);
  // The drop check alone rejects the whole group (the true closures it pushed out need the
  // re-check to come back).
  GncOptions dropOnly;
  dropOnly.recheckRejected = false;
  EXPECT_EQ(solveGnc(dropOnly, data, ref, "manhattan group 100 s4, drop check only").scores.recall,
            1.0);
}

// intel, 1000 outliers in groups of 10, seed 3: the consistent set holds 36 wrong closures;
// the checks drop them from its solution, but the gate was estimated from the first, bent
// solution (noise scale 10x the true one) and lets 30-odd wrong closures fit. Re-estimated
// from the final solution it separates them. Both halves are checked.
TEST(GncChecks, RegateFromTheFinalSolution) {
  const Reference& ref = reference("intel.g2o");
  const tools::OutlierResult data = protocolOutliers(ref, 1000, OutlierMode::Group, 3);
  const OffAndOn r = offAndOn(data, ref, "intel group 1000 s3, final gate",
                              [](GncOptions& g, bool on) { g.regateAtEnd = on; });
  EXPECT_LT(r.off.scores.recall, 0.99) << "the first gate no longer lets wrong closures fit";
  expectExact(r.on, ref);
}

// intel, 1000 local outliers, seed 2: the tail re-admission's wider gate brings no rejected
// closure back, and kept, it let the final re-check take in a wrong closure that fits a
// weakly held stretch (chi2 +7%). The tighter gate stands when nothing comes back.
TEST(GncChecks, KeepTheTighterGateWhenTheTailBringsNothingBack) {
  const Reference& ref = reference("intel.g2o");
  expectExact(solveGnc(GncOptions{}, protocolOutliers(ref, 1000, OutlierMode::Local, 2), ref,
                       "intel local 1000 s2"),
              ref);
}

// parking-garage, 1000 outliers in groups of 10, seed 3: the groups bend the first solution
// (recall 0.35, ATE 70 m), and the gate estimated from its bent tail (8.3 x chi2_dim(0.5),
// the true closures' 0.05) makes bending cheap: at it the consistent-set candidate costs
// more (44437 against 32913). At the candidate's own, tighter gate (0.0012 x) it costs 7.4
// against the bent solution's 2716; judged there first, it is kept and exact. Both halves
// are checked.
TEST(GncConsistentStart, JudgedAtItsOwnTighterGate) {
  const Reference& ref = reference("parking-garage.g2o");
  const tools::OutlierResult data = protocolOutliers(ref, 1000, OutlierMode::Group, 3);
  const OffAndOn r =
      offAndOn(data, ref, "parking-garage group 1000 s3, own gate", [](GncOptions& g, bool on) {
        g.judgeAtOwnGate = on;
        // The final checks cannot get out either (they only chip at the cost); off in the
        // off half, which they would take two minutes to run.
        if (!on) g.recheckRejected = g.dropClusters = false;
      });
  EXPECT_LT(r.off.scores.recall, 0.99) << "the groups no longer bend the first solution";
  expectExact(r.on, ref);
}

// parking-garage, 1000 random outliers, seed 2: at the final tail gate (0.05 x chi2_dim(0.5),
// 30x the median cap, for parking-garage's heavy true tail) the re-check predicts that one
// wrong closure fits for less than its gate, and it does (truncated cost 269.18 -> 268.98):
// the flexible map bends 2 m for it (chi2 +3.9%). Its predicted rise is far beyond the
// noise (100x the median), so admitWithinNoise keeps it out. Both halves are checked.
TEST(GncChecks, AdmitOnlyWithinTheNoise) {
  const Reference& ref = reference("parking-garage.g2o");
  const tools::OutlierResult data = protocolOutliers(ref, 1000, OutlierMode::Random, 2);
  const OffAndOn r = offAndOn(data, ref, "parking-garage random 1000 s2, within noise",
                              [](GncOptions& g, bool on) { g.admitWithinNoise = on; });
  EXPECT_GT(r.off.inlierChi2, 1.01 * ref.optimumChi2) << "no wrong closure fits at the gate";
  expectExact(r.on, ref);
}

// torus3D's first 1000 poses, clean. Its closures' tail reaches a little past c̄² (the tail
// gate about 4.6 × χ²₆(0.5), within widenFactor of c̄² = 16.81, so the gate does not act), and
// at c̄² twelve stiff true closures that hold tension together cost less rejected than kept
// (χ² +8%). Judged at the tail gate, keeping them is cheaper: re-admitted together, the
// answer is the optimum. Both halves are checked.
TEST(GncChecks, AdmitTogetherAtTheTailGateOnCleanTorus) {
  const Reference& ref = reference("torus3D.g2o:1000");
  const tools::OutlierResult data = protocolOutliers(ref, 0, OutlierMode::Random);
  const OffAndOn r = offAndOn(data, ref, "torus3D:1000 clean, together at the tail",
                              [](GncOptions& g, bool on) { g.admitTogetherAtTail = on; });
  EXPECT_GE(r.off.rejected, 5) << "c̄² no longer rejects true closures here";
  EXPECT_GT(r.off.inlierChi2, 1.02 * ref.optimumChi2);
  EXPECT_EQ(r.on.rejected, 0);
  EXPECT_NEAR(r.on.inlierChi2, ref.optimumChi2, 1e-6 * ref.optimumChi2);
}

// Σρ over the loop closures (DCS, Φ = 1) plus rᵀr of the trusted factors: what dcs minimises.
double dcsObjective(const Backend& b) {
  double sum = 0.0;
  for (const auto& f : b.graph().factors()) {
    const double c = f->chi2(b.estimate());
    sum += isUncertain(f->role()) ? kernelCost(KernelType::DCS, c, 1.0) : c;
  }
  return sum;
}

// dcs's optimize() judged its Gauss–Newton steps, and fell back to Levenberg–Marquardt, by rᵀr
// of the re-weighted residuals, Σ w(χ²)·χ², which falls as a closure is pulled away. On
// sphere2500's first 500 poses (450 loop closures, all true), solved at once, that fallback
// ended with 423 of them rejected and Σρ 1248 (from 1340). It now descends Σρ itself
// (heldDescent on the kernels held at the estimate): 251, one closure rejected.
TEST(DcsOptimize, DescendsItsObjectiveNotTheReweightedSquares) {
  const PoseGraphProblem p = buildProblem(loadPrefix("sphere2500.g2o:500"));
  auto dcs = makeBackend("dcs");
  dcs->update(wholeProblemUpdate(p));
  const double before = dcsObjective(*dcs);
  dcs->optimize();
  const double after = dcsObjective(*dcs);
  EXPECT_LT(after, 0.25 * before);
  EXPECT_LE(dcs->rejected().size(), 2u);
  auto lm = makeBackend("lm");
  lm->update(wholeProblemUpdate(p));
  lm->optimize();
  EXPECT_LE(after, dcsObjective(*lm) * (1.0 + 1e-6));  // no worse than the plain optimum
}

}  // namespace
}  // namespace loopd
