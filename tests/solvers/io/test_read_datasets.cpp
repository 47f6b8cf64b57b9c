// Every file of ../shared/datasets reads with the counts of its README, values land where the
// format says, and edge-only files are initialised by composing odometry.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <unordered_map>

#include <Eigen/Cholesky>

#include "io_test_util.h"
#include "solvers/geometry/se2.h"
#include "solvers/geometry/se3.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/problem/pose_graph_problem.h"

namespace loopd::io {
namespace {

using test::datasetPath;

struct Expected {
  const char* file;
  const char* format;
  bool is3d;
  bool hadVertices;
  std::size_t poses;
  std::size_t edges;
  std::size_t landmarks;
};

const Expected kDatasets[] = {
    {"intel.g2o", "g2o", false, true, 1728, 2512, 0},
    {"manhattan.g2o", "g2o", false, false, 3500, 5453, 0},
    {"city10000.g2o", "g2o", false, true, 10000, 20687, 0},
    {"CSAIL.g2o", "g2o", false, false, 1045, 1172, 0},
    {"MIT.g2o", "g2o", false, true, 808, 827, 0},
    {"kitti_00.g2o", "g2o", false, false, 4541, 4677, 0},
    {"sphere2500.g2o", "g2o", true, true, 2500, 4949, 0},
    {"parking-garage.g2o", "g2o", true, true, 1661, 6275, 0},
    {"torus3D.g2o", "g2o", true, true, 5000, 9048, 0},
    {"smallGrid3D.g2o", "g2o", true, true, 125, 297, 0},
    {"tinyGrid3D.g2o", "g2o", true, true, 9, 11, 0},
    {"w100.graph", "toro", false, true, 100, 300, 0},
    {"victoria_park.txt", "victoria", false, false, 6969, 6968 + 3640, 151},
};

class EveryDataset : public ::testing::TestWithParam<Expected> {};

TEST_P(EveryDataset, ReadsWithTheReadmeCounts) {
  const Expected& want = GetParam();
  const Dataset ds = readDataset(datasetPath(want.file));
  EXPECT_EQ(ds.format, want.format);
  EXPECT_EQ(ds.is3d, want.is3d);
  EXPECT_EQ(ds.hadVertices, want.hadVertices);
  EXPECT_EQ(ds.poses.size(), want.poses);
  EXPECT_EQ(ds.edges.size(), want.edges);
  EXPECT_EQ(ds.landmarks.size(), want.landmarks);

  const VertexType poseType = want.is3d ? VertexType::SE3 : VertexType::SE2;
  for (const Vertex& v : ds.poses) {
    ASSERT_EQ(v.type, poseType);
    ASSERT_EQ(v.line > 0, want.hadVertices);
    for (int i = 0; i < vertexValueSize(v.type); ++i) ASSERT_TRUE(std::isfinite(v.value[i]));
    if (want.is3d) {
      const double n = Eigen::Vector4d(v.value[3], v.value[4], v.value[5], v.value[6]).norm();
      ASSERT_NEAR(n, 1.0, 1e-12) << "pose " << v.id;
    }
  }
  if (!want.hadVertices) {  // synthesised poses come sorted by id
    EXPECT_TRUE(std::is_sorted(ds.poses.begin(), ds.poses.end(),
                               [](const Vertex& a, const Vertex& b) { return a.id < b.id; }));
  }
  int previousLine = 0;
  for (std::size_t i = 0; i < ds.edges.size(); ++i) {
    const Edge& e = ds.edges[i];
    ASSERT_EQ(e.index, static_cast<int>(i));
    ASSERT_GT(e.line, previousLine);
    previousLine = e.line;
    const int d = edgeDimension(e.type);
    ASSERT_TRUE(e.information == e.information.transpose()) << "edge " << i;
    // Positive definite on the used block (the unused rest padded with the identity).
    Eigen::Matrix<double, 6, 6> padded = Eigen::Matrix<double, 6, 6>::Identity();
    padded.topLeftCorner(d, d) = e.information.topLeftCorner(d, d);
    const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(padded);
    ASSERT_EQ(llt.info(), Eigen::Success) << "edge " << i;
  }
}

INSTANTIATE_TEST_SUITE_P(Datasets, EveryDataset, ::testing::ValuesIn(kDatasets),
                         [](const ::testing::TestParamInfo<Expected>& info) {
                           std::string name = info.param.file;
                           for (char& c : name) {
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           }
                           return name;
                         });

TEST(Datasets, EveryFileInTheFolderIsCovered) {
  std::set<std::string> covered;
  for (const Expected& e : kDatasets) covered.insert(e.file);
  for (const auto& entry : std::filesystem::directory_iterator(LOOPD_DATASETS_DIR)) {
    const std::string name = entry.path().filename().string();
    if (name == "README.md") continue;
    EXPECT_TRUE(covered.count(name)) << name << " is in the datasets folder but not tested";
  }
}

TEST(Datasets, IntelNumbersMatchTheFile) {
  const Dataset ds = readDataset(datasetPath("intel.g2o"));
  // Line 2: VERTEX_SE2 1 0.144012 -0.004462 -0.017453
  const Vertex& v = ds.poses[1];
  EXPECT_EQ(v.id, 1);
  EXPECT_EQ(v.line, 2);
  EXPECT_EQ(v.value[0], 0.144012);
  EXPECT_EQ(v.value[1], -0.004462);
  EXPECT_EQ(v.value[2], -0.017453);
  // Line 1729: EDGE_SE2 0 1 0.144012 -0.004462 -0.017453 115.187 -9.86523 -7.085 347.418
  //            185.36 224.616
  const Edge& e = ds.edges[0];
  EXPECT_EQ(e.type, EdgeType::BetweenSE2);
  EXPECT_EQ(e.line, 1729);
  EXPECT_EQ(e.from, 0);
  EXPECT_EQ(e.to, 1);
  EXPECT_EQ(e.measurement[0], 0.144012);
  EXPECT_EQ(e.measurement[2], -0.017453);
  Eigen::Matrix3d want;
  want << 115.187, -9.86523, -7.085,  //
      -9.86523, 347.418, 185.36,      //
      -7.085, 185.36, 224.616;
  EXPECT_EQ(Eigen::Matrix3d(e.information.topLeftCorner<3, 3>()), want);
  EXPECT_TRUE(e.information.bottomRows<3>().isZero(0.0));
}

TEST(Datasets, Sphere2500NumbersMatchTheFile) {
  const Dataset ds = readDataset(datasetPath("sphere2500.g2o"));
  // Line 2501: EDGE_SE3:QUAT 0 1 0.341895 -0.0416997 0.0330394 -0.00189341 0.00395691
  // 0.0899835 0.995934  10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 400.021 0.00193512 2.06612 399.993
  // 0.496977 99.203
  const Edge& e = ds.edges[0];
  EXPECT_EQ(e.type, EdgeType::BetweenSE3);
  EXPECT_EQ(e.line, 2501);
  EXPECT_EQ(e.measurement[0], 0.341895);
  EXPECT_EQ(e.measurement[2], 0.0330394);
  const Eigen::Vector4d q(-0.00189341, 0.00395691, 0.0899835, 0.995934);
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(e.measurement[3 + i], q[i] / q.norm(), 1e-15);
  EXPECT_EQ(e.information(0, 0), 10.0);
  EXPECT_EQ(e.information(3, 3), 400.021);
  EXPECT_EQ(e.information(3, 4), 0.00193512);
  EXPECT_EQ(e.information(5, 3), 2.06612);  // mirrored from the upper triangle
  EXPECT_EQ(e.information(4, 5), 0.496977);
  EXPECT_EQ(e.information(5, 5), 99.203);
  EXPECT_EQ(e.information(0, 5), 0.0);
}

TEST(Datasets, VictoriaParkCovariancesAreInverted) {
  const Dataset ds = readDataset(datasetPath("victoria_park.txt"));
  std::size_t odometry = 0, sightings = 0;
  for (const Edge& e : ds.edges) {
    (e.type == EdgeType::BetweenSE2 ? odometry : sightings)++;
  }
  EXPECT_EQ(odometry, 6968u);
  EXPECT_EQ(sightings, 3640u);
  // Line 1: ODOMETRY 0 1 0.000985144 -3.63222e-10 -1.54136e-06 0.0001 0 0 4e-06 0 4e-06
  const Edge& odo = ds.edges[0];
  EXPECT_EQ(odo.measurement[0], 0.000985144);
  EXPECT_NEAR(odo.information(0, 0), 1e4, 1e-8);
  EXPECT_NEAR(odo.information(1, 1), 2.5e5, 1e-6);
  EXPECT_NEAR(odo.information(2, 2), 2.5e5, 1e-6);
  EXPECT_EQ(odo.information(0, 1), 0.0);
  // Line 5: LANDMARK 4 5 11.5387 -3.2007 0.4 0 0.4 — landmark 5's first sighting, from pose 4.
  const auto sighting =
      std::find_if(ds.edges.begin(), ds.edges.end(), [](const Edge& e) { return e.line == 5; });
  ASSERT_NE(sighting, ds.edges.end());
  EXPECT_EQ(sighting->type, EdgeType::PosePoint2);
  EXPECT_EQ(sighting->from, 4);
  EXPECT_EQ(sighting->to, 5);
  EXPECT_NEAR(sighting->information(0, 0), 2.5, 1e-12);
  EXPECT_NEAR(sighting->information(1, 1), 2.5, 1e-12);
  // Landmarks have their own ids (pose 5 and landmark 5 are different variables) and sit at
  // their first sighting.
  const auto lm = std::find_if(ds.landmarks.begin(), ds.landmarks.end(),
                               [](const Vertex& v) { return v.id == 5; });
  ASSERT_NE(lm, ds.landmarks.end());
  EXPECT_EQ(lm->type, VertexType::Point2);
  const Vertex& pose4 = ds.poses[4];
  ASSERT_EQ(pose4.id, 4);
  const Vec2 p = SE2(pose4.value[0], pose4.value[1], pose4.value[2]).transform({11.5387, -3.2007});
  EXPECT_NEAR(lm->value[0], p.x(), 1e-12);
  EXPECT_NEAR(lm->value[1], p.y(), 1e-12);
  EXPECT_TRUE(std::is_sorted(ds.landmarks.begin(), ds.landmarks.end(),
                             [](const Vertex& a, const Vertex& b) { return a.id < b.id; }));
}

TEST(Datasets, W100KeepsEquivalences) {
  const Dataset ds = readDataset(datasetPath("w100.graph"));
  ASSERT_EQ(ds.equivalences.size(), 40u);
  EXPECT_EQ(ds.equivalences[0], std::make_pair(std::int64_t{21}, std::int64_t{1}));
  // EDGE2 1 0 -0.99879 0.0417574 -0.00818381 1 0 1 1 0 0
  EXPECT_EQ(ds.edges[0].from, 1);
  EXPECT_EQ(ds.edges[0].to, 0);
  EXPECT_EQ(ds.edges[0].measurement[0], -0.99879);
  EXPECT_TRUE((ds.edges[0].information.topLeftCorner<3, 3>().isIdentity(0.0)));
}

// An EQUIV pair is the file's statement that two poses are one place, not a measurement that
// can be wrong: trusted like odometry, so no robust variant weighs it.
TEST(Datasets, W100EquivalencesAreTrusted) {
  const PoseGraphProblem p = buildProblem(readDataset(datasetPath("w100.graph")));
  int trusted = 0;
  for (int i = p.graph.size() - 40; i < p.graph.size(); ++i)
    trusted += p.graph[i]->role() == FactorRole::Odometry;
  EXPECT_EQ(trusted, 40);
}

TEST(Toro, InformationOrderIsI11I12I22I33I13I23) {
  const Dataset ds = parseToro("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 10 1 20 30 2 3\n",
                               "order.graph");
  Eigen::Matrix3d want;
  want << 10, 1, 2,  //
      1, 20, 3,      //
      2, 3, 30;
  EXPECT_EQ(Eigen::Matrix3d(ds.edges[0].information.topLeftCorner<3, 3>()), want);
  // The same numbers in g2o's order land elsewhere: I11 I12 I13 I22 I23 I33.
  const Dataset g2o = parseG2o("EDGE_SE2 0 1 1 0 0 10 1 2 20 3 30\n", "order.g2o");
  EXPECT_EQ(Eigen::Matrix3d(g2o.edges[0].information.topLeftCorner<3, 3>()), want);
}

std::unordered_map<std::int64_t, SE2> posesById(const Dataset& ds) {
  std::unordered_map<std::int64_t, SE2> poses;
  for (const Vertex& v : ds.poses) poses[v.id] = SE2(v.value[0], v.value[1], v.value[2]);
  return poses;
}

// Residual of a 2D between edge: (x, y, wrapped θ) of Z⁻¹·Xa⁻¹·Xb.
Eigen::Vector3d residualSE2(const std::unordered_map<std::int64_t, SE2>& poses, const Edge& e) {
  const SE2 z(e.measurement[0], e.measurement[1], e.measurement[2]);
  const SE2 d = z.inverse() * poses.at(e.from).between(poses.at(e.to));
  return {d.x, d.y, wrapAngle(d.theta)};
}

TEST(Odometry, ManhattanComposesTheOdometryChain) {
  const Dataset ds = readDataset(datasetPath("manhattan.g2o"));
  ASSERT_FALSE(ds.hadVertices);
  EXPECT_EQ(ds.poses[0].id, 0);
  EXPECT_EQ(ds.poses[0].value, (std::array<double, 7>{}));
  const auto poses = posesById(ds);
  EXPECT_LT(residualSE2(poses, ds.edges[0]).norm(), 1e-12);
  // Every odometry edge (b = a + 1) lies on the tree, so all of them fit exactly; a loop
  // closure does not (the odometry drifts).
  double worstOdometry = 0.0, worstOther = 0.0;
  for (const Edge& e : ds.edges) {
    double& worst = e.to == e.from + 1 ? worstOdometry : worstOther;
    worst = std::max(worst, residualSE2(poses, e).norm());
  }
  EXPECT_LT(worstOdometry, 1e-9);
  EXPECT_GT(worstOther, 1e-3);
}

TEST(Odometry, EdgesWalkedBackwardsUseTheInverse) {
  // Pose 2 is reached from 1 through an edge written 2 -> 1, pose 3 only by a loop closure.
  const Dataset ds = parseG2o(
      "EDGE_SE2 0 1 1 0 0.5 1 0 0 1 0 1\n"
      "EDGE_SE2 2 1 -1 0.2 -0.3 1 0 0 1 0 1\n"
      "EDGE_SE2 0 3 0 2 1 1 0 0 1 0 1\n",
      "backwards.g2o");
  ASSERT_EQ(ds.poses.size(), 4u);
  const auto poses = posesById(ds);
  for (const Edge& e : ds.edges) EXPECT_LT(residualSE2(poses, e).norm(), 1e-12) << e.line;
}

TEST(Odometry, LoopClosureDoesNotReplaceOdometry) {
  // 0-1-2 is odometry; 0 -> 2 is a loop closure that disagrees with it.
  const Dataset ds = parseG2o(
      "EDGE_SE2 0 2 5 5 0 1 0 0 1 0 1\n"
      "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
      "EDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n",
      "prefer.g2o");
  EXPECT_NEAR(ds.poses[2].value[0], 2.0, 1e-15);
  EXPECT_NEAR(ds.poses[2].value[1], 0.0, 1e-15);
}

TEST(Odometry, OdometryMaySkipIdsTakenByLandmarks) {
  // As in Victoria Park: poses 0, 2, 4 (1 and 3 are landmarks); 0 -> 4 is a loop closure.
  const Dataset ds = parseVictoria(
      "ODOMETRY 0 4 9 9 0 1 0 0 1 0 1\n"
      "ODOMETRY 0 2 1 0 0 1 0 0 1 0 1\n"
      "LANDMARK 2 1 0 1 1 0 1\n"
      "ODOMETRY 2 4 1 0 0 1 0 0 1 0 1\n"
      "LANDMARK 4 3 0 1 1 0 1\n",
      "gaps.txt");
  ASSERT_EQ(ds.poses.size(), 3u);
  EXPECT_EQ(ds.poses[2].id, 4);
  EXPECT_NEAR(ds.poses[2].value[0], 2.0, 1e-15);
  EXPECT_NEAR(ds.poses[2].value[1], 0.0, 1e-15);
}

// The solvers trust odometry, consecutive poses, and judge the rest: "consecutive" is next in
// id order, not id + 1 (before: a file keeping every second pose had no odometry at all, and
// Victoria Park's 151 odometry edges over a landmark's id were loop closures).
TEST(Odometry, TheProblemTrustsNeighboursInIdOrder) {
  const Dataset gaps = parseVictoria(
      "ODOMETRY 0 2 1 0 0 1 0 0 1 0 1\n"
      "LANDMARK 2 1 0 1 1 0 1\n"
      "ODOMETRY 2 4 1 0 0 1 0 0 1 0 1\n"
      "ODOMETRY 0 4 2 0 0 1 0 0 1 0 1\n",
      "gaps.txt");
  const PoseGraphProblem p = buildProblem(gaps);
  EXPECT_EQ(p.graph[0]->role(), FactorRole::Odometry);
  EXPECT_EQ(p.graph[1]->role(), FactorRole::Landmark);
  EXPECT_EQ(p.graph[2]->role(), FactorRole::Odometry);
  EXPECT_EQ(p.graph[3]->role(), FactorRole::LoopClosure);
  // Every second pose of a file: its odometry is still odometry, its closures still closures.
  const PoseGraphProblem every2nd =
      buildProblem(parseG2o("EDGE_SE2 0 2 1 0 0 1 0 0 1 0 1\n"
                            "EDGE_SE2 4 2 -1 0 0 1 0 0 1 0 1\n"
                            "EDGE_SE2 0 4 2 0 0 1 0 0 1 0 1\n",
                            "every2nd.g2o"));
  EXPECT_EQ(every2nd.graph[0]->role(), FactorRole::Odometry);
  EXPECT_EQ(every2nd.graph[1]->role(), FactorRole::Odometry);
  EXPECT_EQ(every2nd.graph[2]->role(), FactorRole::LoopClosure);
  int odometry = 0;
  const PoseGraphProblem victoria = buildProblem(readDataset(datasetPath("victoria_park.txt")));
  for (const auto& f : victoria.graph.factors()) odometry += f->role() == FactorRole::Odometry;
  EXPECT_EQ(odometry, 6968);  // one per pose after the first
}

TEST(Odometry, VictoriaParkFollowsItsOdometry) {
  const Dataset ds = readDataset(datasetPath("victoria_park.txt"));
  const auto poses = posesById(ds);
  for (const Edge& e : ds.edges) {
    if (e.type == EdgeType::BetweenSE2) {
      ASSERT_LT(residualSE2(poses, e).norm(), 1e-9) << e.line;
    }
  }
}

TEST(Odometry, TinyGrid3DWithoutVerticesFitsItsTreeEdges) {
  // Drop the vertex lines of tinyGrid3D: the poses come from composing its SE(3) edges.
  std::istringstream in(test::readText(datasetPath("tinyGrid3D.g2o")));
  std::string edgesOnly, line;
  while (std::getline(in, line)) {
    if (line.rfind("EDGE", 0) == 0) edgesOnly += line + "\n";
  }
  const Dataset ds = parseG2o(edgesOnly, "tiny-edges.g2o");
  ASSERT_FALSE(ds.hadVertices);
  ASSERT_EQ(ds.poses.size(), 9u);
  auto pose = [&](std::int64_t id) {
    return SE3::fromTranslationQuaternion(ds.poses.at(static_cast<std::size_t>(id)).value.data());
  };
  for (const Edge& e : ds.edges) {
    if (e.to != e.from + 1) continue;  // the odometry chain 0-1-…-8 is the tree
    const SE3 z = SE3::fromTranslationQuaternion(e.measurement.data());
    const Vec6 r = logSE3(z.inverse() * pose(e.from).between(pose(e.to)));
    EXPECT_LT(r.norm(), 1e-12) << "edge " << e.from << " -> " << e.to;
  }
}

TEST(Odometry, LandmarksWithoutVerticesSitAtTheirFirstSighting3D) {
  const Dataset ds = parseG2o(
      "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0.7071067811865476 0.7071067811865476"
      " 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n"
      "EDGE_SE3_TRACKXYZ 1 7 2 0 0 1 0 0 1 0 1\n"
      "EDGE_SE3_TRACKXYZ 0 7 9 9 9 1 0 0 1 0 1\n",
      "landmark3d.g2o");
  ASSERT_EQ(ds.landmarks.size(), 1u);
  EXPECT_EQ(ds.landmarks[0].type, VertexType::Point3);
  EXPECT_EQ(ds.landmarks[0].id, 7);
  // Pose 1 is at (1, 0, 0) turned 90° about z: its x axis points along world y.
  EXPECT_NEAR(ds.landmarks[0].value[0], 1.0, 1e-12);
  EXPECT_NEAR(ds.landmarks[0].value[1], 2.0, 1e-12);
  EXPECT_NEAR(ds.landmarks[0].value[2], 0.0, 1e-12);
}

TEST(Robustness, CrlfTabsCommentsAndNoFinalNewline) {
  const Dataset ds = parseG2o(
      "# a comment\r\n"
      "\tVERTEX_SE2\t0 0 0 0\r\n"
      "\r\n"
      "VERTEX_SE2 1 +1.5 0 0   # trailing comment\r\n"
      "   \t \r\n"
      "EDGE_SE2 0 1 1.5 0 0 1 0 0 1 0 1",
      "messy.g2o");
  ASSERT_EQ(ds.poses.size(), 2u);
  EXPECT_EQ(ds.poses[1].value[0], 1.5);
  EXPECT_EQ(ds.poses[1].line, 4);
  ASSERT_EQ(ds.edges.size(), 1u);
  EXPECT_EQ(ds.edges[0].line, 6);
  EXPECT_EQ(ds.edges[0].information(2, 2), 1.0);
}

TEST(Robustness, VeryLongLines) {
  std::string text = "# " + std::string(5'000'000, 'x') + "\n";
  text += "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1" + std::string(1'000'000, ' ') + "\n";
  const Dataset ds = parseG2o(text, "long.g2o");
  EXPECT_EQ(ds.edges.size(), 1u);
  EXPECT_EQ(ds.edges[0].line, 2);
}

TEST(Speed, City10000ReadsQuickly) {
  const auto start = std::chrono::steady_clock::now();
  const Dataset ds = readDataset(datasetPath("city10000.g2o"));
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  std::printf("city10000.g2o: %zu poses, %zu edges read in %.1f ms\n", ds.poses.size(),
              ds.edges.size(), ms);
  // Release reads it in a few tens of ms; the bound leaves room for Debug and sanitizers.
  EXPECT_LT(ms, 2000.0);
}

}  // namespace
}  // namespace loopd::io
