// loopd-outliers' generator and loopd-eval's metrics (library level), plus the two binaries
// end to end on a small dataset.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <set>
#include <string>

#include "solvers/io/dataset_reader.h"
#include "solvers/io/estimate_writer.h"
#include "tools/loopd-eval/trajectory_metrics.h"
#include "tools/loopd-outliers/ambiguous_generator.h"
#include "tools/loopd-outliers/outlier_generator.h"

namespace loopd::tools {
namespace {

const std::string kDatasets = LOOPD_DATASETS_DIR;
const std::string kBin = LOOPD_BINARY_DIR;

TEST(OutlierGenerator, DeterministicAppendedAndWellFormed) {
  const io::Dataset d = io::readDataset(kDatasets + "/intel.g2o");
  for (OutlierMode m : {OutlierMode::Random, OutlierMode::Local, OutlierMode::Group}) {
    OutlierOptions o;
    o.count = 23;
    o.mode = m;
    o.groupSize = 5;
    o.seed = 9;
    const OutlierResult a = addOutliers(d, o), b = addOutliers(d, o);
    ASSERT_EQ(a.outliers.size(), 23u);
    EXPECT_EQ(a.inlierEdges, static_cast<int>(d.edges.size()));
    ASSERT_EQ(a.graph.edges.size(), d.edges.size() + 23);
    for (size_t i = 0; i < a.outliers.size(); ++i) {
      EXPECT_EQ(a.outliers[i], a.inlierEdges + static_cast<int>(i));
      const auto& e = a.graph.edges[a.outliers[i]];
      const auto& f = b.graph.edges[b.outliers[i]];
      EXPECT_EQ(e.from, f.from);
      EXPECT_EQ(e.to, f.to);
      EXPECT_EQ(e.measurement, f.measurement);
      EXPECT_GE(e.to - e.from, 2);  // never an odometry pair
      if (m == OutlierMode::Local) {
        EXPECT_LE(e.to - e.from, o.localWindow);
      }
      EXPECT_GT(e.information(0, 0), 0.0);
    }
    if (m == OutlierMode::Group) {  // groups of 5 consecutive pairs share one measurement
      for (int g = 0; g < 4; ++g)
        for (int j = 1; j < 5; ++j) {
          const auto& first = a.graph.edges[a.outliers[g * 5]];
          const auto& e = a.graph.edges[a.outliers[g * 5 + j]];
          EXPECT_EQ(e.measurement, first.measurement);
          EXPECT_EQ(e.from, first.from + j);
          EXPECT_EQ(e.to, first.to + j);
        }
    }
    o.seed = 10;
    const OutlierResult c = addOutliers(d, o);
    EXPECT_NE(c.graph.edges.back().from * 100000 + c.graph.edges.back().to,
              a.graph.edges.back().from * 100000 + a.graph.edges.back().to);
  }
  const std::string json = outlierTruthJson("x.g2o", OutlierOptions{}, addOutliers(d, {}));
  EXPECT_EQ(jsonIntArray(json, "outliers").size(), 100u);
  EXPECT_EQ(jsonNumber(json, "inlier_edges", -1), static_cast<double>(d.edges.size()));
}

TEST(OutlierGenerator, ThreeDimensional) {
  const io::Dataset d = io::readDataset(kDatasets + "/smallGrid3D.g2o");
  OutlierOptions o;
  o.count = 10;
  const OutlierResult a = addOutliers(d, o);
  for (int i : a.outliers) {
    const auto& e = a.graph.edges[i];
    EXPECT_EQ(e.type, io::EdgeType::BetweenSE3);
    const double qn = std::sqrt(e.measurement[3] * e.measurement[3] + e.measurement[4] * e.measurement[4] +
                                e.measurement[5] * e.measurement[5] + e.measurement[6] * e.measurement[6]);
    EXPECT_NEAR(qn, 1.0, 1e-12);
  }
}

TEST(TrajectoryMetrics, AlignmentInvariantAteAndRpe) {
  const io::Dataset ref = io::readDataset(kDatasets + "/intel.g2o");
  io::Dataset moved = ref;
  const double c = std::cos(0.7), s = std::sin(0.7);
  for (auto& v : moved.poses) {
    const double x = v.value[0], y = v.value[1];
    v.value[0] = c * x - s * y + 5.0;
    v.value[1] = s * x + c * y - 2.0;
    v.value[2] += 0.7;
  }
  const TrajectoryErrors e = trajectoryErrors(ref, moved);
  EXPECT_EQ(e.poses, static_cast<int>(ref.poses.size()));
  EXPECT_LT(e.ateRmse, 1e-9);
  EXPECT_LT(e.rpeTrans, 1e-9);
  EXPECT_LT(e.rpeRotDeg, 1e-6);
  moved.poses[10].value[0] += 1.0;  // one pose off by ~1 m
  const TrajectoryErrors f = trajectoryErrors(ref, moved);
  EXPECT_GT(f.ateRmse, 0.9 / std::sqrt(ref.poses.size()));
  EXPECT_NEAR(f.ateMax, 1.0, 0.05);
  EXPECT_GT(f.rpeTrans, 0.0);
}

TEST(TrajectoryMetrics, PrecisionRecall) {
  const DecisionScores s = scoreRejections({1, 2, 3, 9}, {1, 2, 3, 4, 5, 6});
  EXPECT_EQ(s.truePositives, 3);
  EXPECT_EQ(s.falsePositives, 1);
  EXPECT_EQ(s.falseNegatives, 3);
  EXPECT_DOUBLE_EQ(s.precision, 0.75);
  EXPECT_DOUBLE_EQ(s.recall, 0.5);
  const DecisionScores none = scoreRejections({}, {});
  EXPECT_DOUBLE_EQ(none.precision, 1.0);
  EXPECT_DOUBLE_EQ(none.recall, 1.0);
  EXPECT_EQ(jsonIntArray("{\"rejected\": [ 4, 5,6 ], \"x\": 1}", "rejected"),
            (std::vector<std::int64_t>{4, 5, 6}));
  EXPECT_TRUE(jsonIntArray("{\"rejected\": []}", "rejected").empty());
}

TEST(TrajectoryMetrics, InlierChi2SkipsOutliers) {
  const io::Dataset d = io::readDataset(kDatasets + "/intel.g2o");
  OutlierOptions o;
  o.count = 5;
  const OutlierResult r = addOutliers(d, o);
  std::vector<std::int64_t> out(r.outliers.begin(), r.outliers.end());
  const double withOut = inlierChi2(r.graph, d, out);
  const double plain = inlierChi2(d, d, {});
  EXPECT_NEAR(withOut, plain, 1e-9 * plain);
  EXPECT_GT(inlierChi2(r.graph, d, {}), plain);
}

TEST(OutliersEvalBinaries, EndToEnd) {
  const std::string dir = ::testing::TempDir();
  const std::string graph = dir + "/grid_out.g2o", truth = dir + "/grid_truth.json",
                    json = dir + "/grid_eval.json";
  const std::string gen = kBin + "/tools/loopd-outliers " + kDatasets +
                          "/smallGrid3D.g2o --count 7 --mode group --group-size 3 --seed 5 --out " +
                          graph + " --truth " + truth;
  ASSERT_EQ(std::system(gen.c_str()), 0) << gen;
  const io::Dataset g = io::readDataset(graph);
  const std::string t = readTextFile(truth);
  EXPECT_EQ(jsonIntArray(t, "outliers").size(), 7u);
  EXPECT_EQ(g.edges.size(), static_cast<size_t>(jsonNumber(t, "inlier_edges", 0)) + 7);
  const std::string eval = kBin + "/tools/loopd-eval --reference " + kDatasets +
                           "/smallGrid3D.g2o --estimate " + kDatasets + "/smallGrid3D.g2o --truth " +
                           truth + " --graph " + graph + " --json " + json + " > /dev/null";
  ASSERT_EQ(std::system(eval.c_str()), 0) << eval;
  const std::string e = readTextFile(json);
  EXPECT_NEAR(jsonNumber(e, "ate_rmse", -1), 0.0, 1e-9);
  EXPECT_EQ(std::system((kBin + "/tools/loopd-outliers 2>/dev/null").c_str()) != 0, true);
}

TEST(AmbiguousGenerator, GroupsHoldTheTrueEdgeAndWrongDecoys) {
  const io::Dataset d = io::readDataset(kDatasets + "/intel.g2o");
  for (DecoyMode mode : {DecoyMode::Target, DecoyMode::Measurement, DecoyMode::Mixed}) {
    AmbiguousOptions o;
    o.count = 25;
    o.alternatives = 4;
    o.null = mode == DecoyMode::Mixed;
    o.decoys = mode;
    o.seed = 3;
    const AmbiguousResult a = makeAmbiguous(d, o), b = makeAmbiguous(d, o);
    ASSERT_EQ(a.graph.hypotheses.size(), 25u);
    EXPECT_EQ(a.graph.edges.size(), d.edges.size() + 25 * 3);
    EXPECT_EQ(a.decoys.size(), 75u);
    EXPECT_EQ(a.trueChoice, b.trueChoice);
    EXPECT_EQ(a.decoys, b.decoys);
    std::set<int> decoys(a.decoys.begin(), a.decoys.end());
    for (size_t g = 0; g < a.graph.hypotheses.size(); ++g) {
      const io::HypothesisGroup& h = a.graph.hypotheses[g];
      EXPECT_EQ(h.count, 4);
      EXPECT_EQ(h.null, o.null);
      const io::Edge& truth = a.graph.edges[a.trueEdges[g]];
      EXPECT_EQ(a.trueEdges[g], h.firstEdge + a.trueChoice[g]);
      EXPECT_FALSE(decoys.count(a.trueEdges[g]));
      EXPECT_GE(std::llabs(truth.to - truth.from), 2);  // a loop closure of the input
      for (int k = 0; k < h.count; ++k) {
        if (k == a.trueChoice[g]) continue;
        const io::Edge& e = a.graph.edges[h.firstEdge + k];
        EXPECT_TRUE(decoys.count(h.firstEdge + k));
        const bool sameKeys = e.from == truth.from && e.to == truth.to;
        // Wrong target with the same measurement, or the same keys with a wrong one.
        EXPECT_NE(sameKeys, e.measurement == truth.measurement);
        if (mode == DecoyMode::Target && !sameKeys) {
          EXPECT_LE(std::max(std::llabs(e.from - truth.from), std::llabs(e.to - truth.to)), 10);
        }
        if (mode == DecoyMode::Measurement) EXPECT_TRUE(sameKeys);
      }
    }
  }
  AmbiguousOptions tooMany;
  tooMany.count = 100000;
  EXPECT_THROW(makeAmbiguous(d, tooMany), std::invalid_argument);
}

TEST(OutliersEvalBinaries, AmbiguousEndToEnd) {
  // loopd-outliers --ambiguous → loopd-solve --solver mh → loopd-eval's choice accuracy; a
  // solver without hypotheses reports its choices too.
  const std::string dir = ::testing::TempDir();
  const std::string graph = dir + "/intel_amb.g2o", truth = dir + "/intel_amb.json",
                    stats = dir + "/intel_amb_stats.json", est = dir + "/intel_amb_est.g2o",
                    ref = dir + "/intel_ref.g2o", json = dir + "/intel_amb_eval.json";
  const std::string gen = kBin + "/tools/loopd-outliers " + kDatasets +
                          "/intel.g2o --ambiguous 30 --null --decoys mixed --seed 4 --out " + graph +
                          " --truth " + truth + " 2>/dev/null";
  ASSERT_EQ(std::system(gen.c_str()), 0) << gen;
  const std::string solveRef = kBin + "/tools/loopd-solve " + kDatasets +
                               "/intel.g2o --solver isam2 --incremental -q --out " + ref;
  ASSERT_EQ(std::system(solveRef.c_str()), 0) << solveRef;
  const std::string solve = kBin + "/tools/loopd-solve " + graph +
                            " --solver mh --incremental -q --max-hypotheses 5 --stats " + stats +
                            " --out " + est;
  ASSERT_EQ(std::system(solve.c_str()), 0) << solve;
  const std::string s = readTextFile(stats);
  EXPECT_EQ(jsonIntArray(s, "chosen"), jsonIntArray(readTextFile(truth), "true_choice"));
  EXPECT_EQ(jsonNumber(s, "max_hypotheses", 0), 5);
  EXPECT_GE(jsonNumber(s, "live_hypotheses", 0), 1);
  const std::string eval = kBin + "/tools/loopd-eval --reference " + ref + " --estimate " + est +
                           " --truth " + truth + " --stats " + stats + " --graph " + graph +
                           " --json " + json + " > /dev/null";
  ASSERT_EQ(std::system(eval.c_str()), 0) << eval;
  const std::string e = readTextFile(json);
  EXPECT_EQ(jsonNumber(e, "chosen_accuracy", 0), 1.0);
  EXPECT_EQ(jsonNumber(e, "precision", 0), 1.0);
  EXPECT_EQ(jsonNumber(e, "recall", 0), 1.0);
  EXPECT_LT(jsonNumber(e, "ate_rmse", 1), 1e-3);

  const std::string plain = kBin + "/tools/loopd-solve " + graph +
                            " --solver isam2 --incremental -q --stats " + stats;
  ASSERT_EQ(std::system(plain.c_str()), 0) << plain;
  EXPECT_EQ(jsonIntArray(readTextFile(stats), "chosen").size(), 30u);
  const std::string badK = kBin + "/tools/loopd-solve " + graph + " --max-hypotheses 0 2>/dev/null";
  EXPECT_NE(std::system(badK.c_str()), 0);
}

}  // namespace
}  // namespace loopd::tools
