// loopd-outliers' generator and loopd-eval's metrics (library level), plus the two binaries
// end to end on a small dataset.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "solvers/io/dataset_reader.h"
#include "solvers/io/estimate_writer.h"
#include "tools/loopd-eval/json_input.h"
#include "tools/loopd-eval/trajectory_metrics.h"
#include "tools/loopd-outliers/ambiguous_generator.h"
#include "tools/loopd-outliers/outlier_generator.h"

namespace loopd::tools {
namespace {

const std::string kDatasets = LOOPD_DATASETS_DIR;
const std::string kBin = LOOPD_BINARY_DIR;
const std::string kSource = LOOPD_SOURCE_DIR;

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
    const double qn =
        std::sqrt(e.measurement[3] * e.measurement[3] + e.measurement[4] * e.measurement[4] +
                  e.measurement[5] * e.measurement[5] + e.measurement[6] * e.measurement[6]);
    EXPECT_NEAR(qn, 1.0, 1e-12);
  }
}

// --vertigo: generateDataset.py's measurements, near the identity (axes ~ N(0, 0.3 m), angles
// ~ N(0, 10°)); the default's rotations are uniform, so the spread tells the two apart.
TEST(OutlierGenerator, VertigoMeasurementsNearTheIdentity) {
  auto spread = [](const OutlierResult& r, int k) {
    double sum = 0.0, sq = 0.0;
    for (int i : r.outliers) {
      const double x = r.graph.edges[i].measurement[k];
      sum += x, sq += x * x;
    }
    const double n = static_cast<double>(r.outliers.size()), mean = sum / n;
    return std::sqrt(sq / n - mean * mean);
  };
  const io::Dataset d2 = io::readDataset(kDatasets + "/intel.g2o");
  OutlierOptions o;
  o.count = 4000;
  o.measurement = OutlierMeasurement::Vertigo;
  const OutlierResult v = addOutliers(d2, o);
  EXPECT_NEAR(spread(v, 0), 0.3, 0.02);
  EXPECT_NEAR(spread(v, 1), 0.3, 0.02);
  EXPECT_NEAR(spread(v, 2), 10.0 * M_PI / 180.0, 0.01);
  o.measurement = OutlierMeasurement::Uniform;
  EXPECT_NEAR(spread(addOutliers(d2, o), 2), M_PI / std::sqrt(3.0), 0.1);  // uniform on ±π
  EXPECT_NE(outlierTruthJson("x.g2o", o, v).find("\"measurement\": \"uniform\""),
            std::string::npos);

  const io::Dataset d3 = io::readDataset(kDatasets + "/smallGrid3D.g2o");
  o.measurement = OutlierMeasurement::Vertigo;
  const OutlierResult v3 = addOutliers(d3, o);
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(spread(v3, k), 0.3, 0.02);
  double largest = 0.0;
  for (int i : v3.outliers) {
    const auto& m = v3.graph.edges[i].measurement;
    const Eigen::Quaterniond q(m[6], m[3], m[4], m[5]);
    EXPECT_NEAR(q.norm(), 1.0, 1e-12);
    EXPECT_GE(q.w(), 0.0);
    largest = std::max(largest, Eigen::AngleAxisd(q).angle());
  }
  EXPECT_LT(largest, 90.0 * M_PI / 180.0);  // three 10° angles: never near a half turn
  EXPECT_NE(outlierTruthJson("x.g2o", o, v3).find("\"measurement\": \"vertigo\""),
            std::string::npos);
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
                           "/smallGrid3D.g2o --estimate " + kDatasets +
                           "/smallGrid3D.g2o --truth " + truth + " --graph " + graph + " --json " +
                           json + " > /dev/null";
  ASSERT_EQ(std::system(eval.c_str()), 0) << eval;
  const std::string e = readTextFile(json);
  EXPECT_NEAR(jsonNumber(e, "ate_rmse", -1), 0.0, 1e-9);
  EXPECT_EQ(std::system((kBin + "/tools/loopd-outliers 2>/dev/null").c_str()) != 0, true);
}

// --vertigo also takes generateDataset.py's local window (20) unless --window is given.
TEST(OutliersEvalBinaries, VertigoLocalWindow) {
  const std::string dir = ::testing::TempDir();
  const std::string graph = dir + "/intel_vertigo.g2o", truth = dir + "/intel_vertigo.json";
  auto generate = [&](const std::string& extra) {
    const std::string gen = kBin + "/tools/loopd-outliers " + kDatasets +
                            "/intel.g2o --count 500 --mode local --vertigo --seed 3 --out " +
                            graph + " --truth " + truth + extra + " 2>/dev/null";
    EXPECT_EQ(std::system(gen.c_str()), 0) << gen;
    const io::Dataset g = io::readDataset(graph);
    std::int64_t widest = 0;
    for (std::int64_t i : jsonIntArray(readTextFile(truth), "outliers"))
      widest = std::max(widest, g.edges[i].to - g.edges[i].from);
    return widest;
  };
  EXPECT_EQ(generate(""), 20);
  EXPECT_GT(generate(" --window 50"), 20);
  EXPECT_NE(readTextFile(truth).find("\"measurement\": \"vertigo\""), std::string::npos);
  const std::string both = kBin + "/tools/loopd-outliers " + kDatasets +
                           "/intel.g2o --ambiguous 5 --vertigo --out " + graph + " --truth " +
                           truth + " 2>/dev/null";
  EXPECT_NE(std::system(both.c_str()), 0);
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
                          "/intel.g2o --ambiguous 30 --null --decoys mixed --seed 4 --out " +
                          graph + " --truth " + truth + " 2>/dev/null";
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

  const std::string plain =
      kBin + "/tools/loopd-solve " + graph + " --solver isam2 --incremental -q --stats " + stats;
  ASSERT_EQ(std::system(plain.c_str()), 0) << plain;
  EXPECT_EQ(jsonIntArray(readTextFile(stats), "chosen").size(), 30u);
  const std::string badK = kBin + "/tools/loopd-solve " + graph + " --max-hypotheses 0 2>/dev/null";
  EXPECT_NE(std::system(badK.c_str()), 0);
}

// A results.csv's lines without their ends (Python's csv writes "\r\n").
std::vector<std::string> csvLines(const std::string& path) {
  std::ifstream csv(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(csv, line);) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    lines.push_back(line);
  }
  return lines;
}

// tools/compare end to end on a small setting: the reference solve, the outliers (here with
// --vertigo, recorded as mode vertigo-local), a variant's run and its scores in results.csv.
TEST(CompareScript, VertigoRowsEndToEnd) {
  const std::string out = ::testing::TempDir() + "/compare_vertigo";
  const std::string cmd = "/usr/bin/python3 " + kSource + "/tools/compare --build " + kBin +
                          " --datasets-dir " + kDatasets +
                          " --variants gnc-tls --datasets intel.g2o --modes local --counts 20 "
                          "--seeds 1 --vertigo --no-plots --out " +
                          out + " > /dev/null 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  const std::vector<std::string> lines = csvLines(out + "/results.csv");
  ASSERT_EQ(lines.size(), 2u) << "a header and one row: one setting";
  const std::string &header = lines[0], &row = lines[1];
  EXPECT_EQ(row.rfind("intel,vertigo-local,20,1,gnc-tls,ok,", 0), 0u) << row;
  // The last column names the CPU that ran it (timings, and rarely decisions, differ across CPUs).
  ASSERT_GE(header.size(), 8u);
  EXPECT_EQ(header.substr(header.size() - 8), ",machine") << header;
  EXPECT_NE(row.back(), ',') << "a run records its machine: " << row;
  // Both tables beside it: the long one per variant and the compact one the README shows.
  std::ifstream tablesFile(out + "/tables.md");
  const std::string tables((std::istreambuf_iterator<char>(tablesFile)),
                           std::istreambuf_iterator<char>());
  EXPECT_NE(tables.find("| intel | vertigo-local 20 | gnc-tls | 1/1 |"), std::string::npos)
      << tables;
  EXPECT_NE(tables.find("| dataset | outliers | gnc-tls |"), std::string::npos) << tables;
}

// A partial re-run merged into a full table: the row of the same dataset, setting, seed and
// variant is replaced where it stood, a new one is added at the end, the rest is untouched,
// and a changed verdict is reported. The table predates the machine column: its rows keep it
// empty, the merged rows get --machine's label.
TEST(CompareScript, MergeIntoReplacesTheSameRunsAndAddsTheRest) {
  const std::string dir = ::testing::TempDir() + "/compare_merge";
  ASSERT_EQ(std::system(("rm -rf " + dir + " && mkdir -p " + dir).c_str()), 0);
  const std::string header =
      "dataset,mode,count,seed,variant,status,ate_rmse,rpe_trans,rpe_rot_deg,precision,recall,"
      "rejected,inlier_chi2,reference_chi2,chi2_excess,solve_s,update_ms_mean,update_ms_p99,"
      "update_ms_max\n";
  std::ofstream(dir + "/table.csv")
      << header << "intel,random,100,1,dcs,timeout,,,,,,,,,,300.2,,,\n"
      << "intel,random,100,2,dcs,ok,0.1,0.01,0.1,1,1,100,45,45,0,2.0,1,2,3\n";
  std::ofstream(dir + "/rerun.csv")
      << header << "intel,random,100,1,dcs,ok,0.1,0.01,0.1,1,0.98,98,50,45,0.11,250.0,1,2,3\n"
      << "intel,group,100,1,dcs,ok,0.1,0.01,0.1,1,1,100,45,45,0,3.0,1,2,3\n";
  const std::string cmd = "/usr/bin/python3 " + kSource + "/tools/compare --rows " + dir +
                          "/rerun.csv --merge-into " + dir + "/table.csv --machine cpu-x 2> " +
                          dir + "/log.txt";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  const std::vector<std::string> lines = csvLines(dir + "/table.csv");
  ASSERT_EQ(lines.size(), 4u) << "a header and three rows";
  EXPECT_EQ(lines[1].rfind("intel,random,100,1,dcs,ok,0.1,", 0), 0u) << lines[1];
  EXPECT_NE(lines[1].find(",250.0,"), std::string::npos) << "the re-run's own figures";
  EXPECT_EQ(lines[0], header.substr(0, header.size() - 1) + ",machine");
  EXPECT_EQ(lines[1].substr(lines[1].size() - 6), ",cpu-x") << lines[1];
  EXPECT_EQ(lines[2], "intel,random,100,2,dcs,ok,0.1,0.01,0.1,1,1,100,45,45,0,2.0,1,2,3,")
      << "a row not merged keeps its figures and names no machine";
  EXPECT_EQ(lines[3].rfind("intel,group,100,1,dcs,ok,", 0), 0u) << lines[3];
  EXPECT_EQ(lines[3].substr(lines[3].size() - 6), ",cpu-x") << lines[3];
  std::ifstream logFile(dir + "/log.txt");
  const std::string log((std::istreambuf_iterator<char>(logFile)),
                        std::istreambuf_iterator<char>());
  EXPECT_NE(log.find("intel random 100 1 dcs: timeout -> misses"), std::string::npos) << log;
  EXPECT_NE(log.find("1 rows replaced, 1 added"), std::string::npos) << log;
  const std::string orphan = "/usr/bin/python3 " + kSource + "/tools/compare --rows " + dir +
                             "/rerun.csv > /dev/null 2>&1";
  EXPECT_NE(std::system(orphan.c_str()), 0) << "--rows without --merge-into is refused";
}

// A shell command's exit status (128 + the signal if it was killed).
int exitStatus(const std::string& cmd) {
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

// Arguments tools/compare can check before running anything are usage errors: exit status 2,
// a message naming the option or file (no Python traceback), and nothing run (--out is not
// even created). Datasets must be in --datasets-dir, modes and variants are those the tools'
// --help lists (modes also as vertigo-MODE).
TEST(CompareScript, BadArgumentsAreUsageErrorsBeforeAnyRun) {
  const std::string dir = ::testing::TempDir() + "/compare_args";
  ASSERT_EQ(std::system(("rm -rf " + dir + " && mkdir -p " + dir).c_str()), 0);
  const std::string base = "/usr/bin/python3 " + kSource + "/tools/compare --build " + kBin +
                           " --datasets-dir " + kDatasets +
                           " --no-plots --datasets tinyGrid3D.g2o --modes random --counts 3"
                           " --variants lm --out " +
                           dir + "/out ";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"--counts abc", "--counts"},
      {"--seeds x,y", "--seeds"},
      {"--counts 1,-2", "--counts"},
      {"--timeout 0", "--timeout"},
      {"--replot " + dir + "/missing.csv", "missing.csv"},
      {"--datasets nonexistent.g2o", "nonexistent.g2o"},
      {"--modes bogus", "bogus"},
      {"--modes vertigo-bogus", "vertigo-bogus"},
      {"--variants lm,foo", "foo"}};
  for (const auto& [args, named] : cases) {
    const std::string log = dir + "/log.txt";
    EXPECT_EQ(exitStatus(base + args + " > /dev/null 2> " + log), 2) << args;
    const std::string err = readTextFile(log);
    EXPECT_NE(err.find("compare: error: "), std::string::npos) << args << ":\n" << err;
    EXPECT_NE(err.find(named), std::string::npos) << args << ":\n" << err;
    EXPECT_EQ(err.find("Traceback"), std::string::npos) << args << ":\n" << err;
  }
  EXPECT_NE(exitStatus("test -e " + dir + "/out"), 0) << "nothing ran";
}

// A tool that fails says why: its own error line, not the last line of the usage text it
// prints after it. A failed solve is a row of status error (exit status 0: failures are
// results); a setting that could not be set up (loopd-outliers failed) has no rows, so the
// run exits 1, after writing the others. The build here wraps the real tools to fail so.
TEST(CompareScript, FailuresNameTheToolsReason) {
  const std::string dir = ::testing::TempDir() + "/compare_fail";
  const std::string tools = dir + "/build/tools";
  ASSERT_EQ(std::system(("rm -rf " + dir + " && mkdir -p " + tools + " && ln -s " + kBin +
                         "/tools/loopd-eval " + tools + "/")
                            .c_str()),
            0);
  std::ofstream(tools + "/loopd-solve")
      << "#!/bin/sh\ncase \" $* \" in *\" --solver dcs \"*) exec " << kBin
      << "/tools/loopd-solve \"$@\" --max-iterations 0 ;; esac\nexec " << kBin
      << "/tools/loopd-solve \"$@\"\n";
  std::ofstream(tools + "/loopd-outliers")
      << "#!/bin/sh\ncase \" $* \" in *\" --seed 2 \"*) exec " << kBin
      << "/tools/loopd-outliers \"$@\" --group-size 0 ;; esac\nexec " << kBin
      << "/tools/loopd-outliers \"$@\"\n";
  ASSERT_EQ(
      std::system(("chmod +x " + tools + "/loopd-solve " + tools + "/loopd-outliers").c_str()), 0);
  const std::string cmd = "/usr/bin/python3 " + kSource + "/tools/compare --build " + dir +
                          "/build --datasets-dir " + kDatasets +
                          " --no-plots --datasets tinyGrid3D.g2o --modes random --counts 3"
                          " --variants lm,dcs --out " +
                          dir + "/out > /dev/null 2> " + dir + "/log.txt --seeds ";
  EXPECT_EQ(exitStatus(cmd + "1"), 0);
  std::string log = readTextFile(dir + "/log.txt");
  EXPECT_NE(log.find("dcs: error: loopd-solve: --max-iterations"), std::string::npos) << log;
  std::vector<std::string> lines = csvLines(dir + "/out/results.csv");
  ASSERT_EQ(lines.size(), 3u);
  EXPECT_EQ(lines[1].rfind("tinyGrid3D,random,3,1,lm,ok,", 0), 0u) << lines[1];
  EXPECT_EQ(lines[2].rfind("tinyGrid3D,random,3,1,dcs,error,", 0), 0u) << lines[2];

  EXPECT_EQ(exitStatus(cmd + "1,2"), 1);
  log = readTextFile(dir + "/log.txt");
  EXPECT_NE(log.find("loopd-outliers: --group-size"), std::string::npos) << log;
  EXPECT_NE(log.find("could not be set up"), std::string::npos) << log;
  lines = csvLines(dir + "/out/results.csv");
  EXPECT_EQ(lines.size(), 3u) << "seed 1's rows are written";
}

}  // namespace
}  // namespace loopd::tools
