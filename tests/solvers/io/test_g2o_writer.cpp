// writeG2oGraph then readDataset gives back the same graph bit for bit; writeG2oVertices
// writes the estimate in the input's kind with the input's ids.
#include <gtest/gtest.h>

#include <filesystem>
#include <sstream>

#include "io_test_util.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/io/estimate_writer.h"
#include "solvers/problem/pose_graph_problem.h"

namespace loopd::io {
namespace {

using test::datasetPath;

Dataset roundTrip(const Dataset& ds) {
  const test::ScratchFile file(".g2o");
  writeG2oGraph(file.path(), ds);
  return readDataset(file.path());
}

class RoundTrip : public ::testing::TestWithParam<const char*> {};

TEST_P(RoundTrip, WriteThenReadGivesTheSameGraph) {
  const Dataset ds = readDataset(datasetPath(GetParam()));
  const Dataset back = roundTrip(ds);
  EXPECT_EQ(back.format, "g2o");
  EXPECT_TRUE(back.hadVertices);  // synthesised poses are written as vertices
  test::expectSameGraph(ds, back);
}

// 2D and 3D, with and without vertices in the input, and TORO (its information reordered).
INSTANTIATE_TEST_SUITE_P(Datasets, RoundTrip,
                         ::testing::Values("intel.g2o", "manhattan.g2o", "sphere2500.g2o",
                                           "parking-garage.g2o", "w100.graph"));

TEST(RoundTrip, LandmarksIn2DAnd3D) {
  const std::string info3 = " 1 0.1 0.2 2 0.3 3";
  const Dataset ds2 = parseG2o(
      "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0.3\nVERTEX_XY 7 0.1 2.5\n"
      "EDGE_SE2 0 1 1 0 0.3 5 1 0.5 6 0.25 7\n"
      "EDGE_SE2_XY 1 7 -1 2.4 4 0.5 3\n",
      "lm2.g2o");
  test::expectSameGraph(ds2, roundTrip(ds2));
  const Dataset ds3 = parseG2o(
      "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 2 3 0.1 0.2 0.3 0.9\n"
      "VERTEX_TRACKXYZ 9 1 1 1\n"
      "EDGE_SE3:QUAT 0 1 1 2 3 0.1 0.2 0.3 0.9 "
      "10 1 0 0 0 0 10 0 0 0 0 10 0 0 0 20 1 0 20 1 20\n"
      "EDGE_SE3_TRACKXYZ 1 9 0.5 0.5 0.5" +
          info3 + "\n",
      "lm3.g2o");
  test::expectSameGraph(ds3, roundTrip(ds3));
}

// g2o has no EQUIV: the pairs are written as what they are solved as, identity edges of
// information kEquivalenceInformation after every other edge (which keep their indices), so
// the written graph is the same problem (before: dropped, a different graph).
TEST(RoundTrip, ToroEquivalencesBecomeIdentityEdgesAtTheEnd) {
  const Dataset ds = readDataset(datasetPath("w100.graph"));
  ASSERT_EQ(ds.equivalences.size(), 40u);
  const Dataset back = roundTrip(ds);
  EXPECT_TRUE(back.equivalences.empty());
  ASSERT_EQ(back.edges.size(), ds.edges.size() + ds.equivalences.size());
  for (std::size_t k = 0; k < ds.equivalences.size(); ++k) {
    const Edge& e = back.edges[ds.edges.size() + k];
    EXPECT_EQ(e.type, EdgeType::BetweenSE2);
    EXPECT_EQ(e.from, ds.equivalences[k].first);
    EXPECT_EQ(e.to, ds.equivalences[k].second);
    EXPECT_EQ(e.measurement, (std::array<double, 7>{}));
    const Eigen::Matrix3d info = e.information.topLeftCorner<3, 3>();
    EXPECT_TRUE(info == Eigen::Matrix3d::Identity() * kEquivalenceInformation) << info;
  }
  const PoseGraphProblem original = buildProblem(ds), written = buildProblem(back);
  ASSERT_EQ(written.graph.size(), original.graph.size());
  EXPECT_DOUBLE_EQ(written.graph.chi2(written.initial), original.graph.chi2(original.initial));
}

TEST(RoundTrip, VictoriaParkBecomesG2o) {
  // Its odometry skips the ids its landmarks use, so the ids fit g2o's single id space.
  const Dataset ds = readDataset(datasetPath("victoria_park.txt"));
  test::expectSameGraph(ds, roundTrip(ds));
}

TEST(RoundTrip, LandmarkIdThatIsAlsoAPoseIdIsRefused) {
  // Victoria Park numbers landmarks apart from poses; g2o cannot, so writing refuses.
  const Dataset ds =
      parseVictoria("ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nLANDMARK 1 1 2 0 1 0 1\n", "ids.txt");
  const test::ScratchFile file(".g2o");
  try {
    writeG2oGraph(file.path(), ds);
    FAIL();
  } catch (const DatasetError& e) {
    EXPECT_EQ(e.reason(), "landmark 1 has the id of a pose; g2o has one id space for both");
  }
}

TEST(WriteVertices, OneLinePerVertexOfTheInputsKind) {
  const Dataset ds = readDataset(datasetPath("intel.g2o"));
  const test::ScratchFile file(".g2o");
  writeG2oVertices(file.path(), ds);
  const std::string text = test::readText(file.path());
  std::istringstream lines(text);
  std::string line;
  std::size_t count = 0;
  while (std::getline(lines, line)) {
    EXPECT_EQ(line.rfind("VERTEX_SE2 " + std::to_string(ds.poses[count].id) + " ", 0), 0u) << line;
    ++count;
  }
  EXPECT_EQ(count, ds.poses.size());
  EXPECT_EQ(text.substr(0, text.find('\n')), "VERTEX_SE2 0 0 0 0");

  // The vertex lines read back exactly: pair them with the file's edges.
  std::istringstream original(test::readText(datasetPath("intel.g2o")));
  std::string edges;
  while (std::getline(original, line)) {
    if (line.rfind("EDGE", 0) == 0) edges += line + "\n";
  }
  const Dataset back = parseG2o(text + edges, "estimate+edges.g2o");
  test::expectSameGraph(ds, back);
}

TEST(WriteVertices, ThreeDAndLandmarks) {
  const Dataset ds = parseG2o(
      "VERTEX_SE3:QUAT 4 1 2 3 0 0 0 1\nVERTEX_TRACKXYZ 9 0.5 -0.25 1e-300\n"
      "EDGE_SE3_TRACKXYZ 4 9 1 1 1 1 0 0 1 0 1\n",
      "kinds.g2o");
  const test::ScratchFile file(".g2o");
  writeG2oVertices(file.path(), ds);
  EXPECT_EQ(test::readText(file.path()),
            "VERTEX_SE3:QUAT 4 1 2 3 0 0 0 1\nVERTEX_TRACKXYZ 9 0.5 -0.25 1e-300\n");
}

TEST(WriteVertices, FullPrecision) {
  Dataset ds;
  Vertex v;
  v.type = VertexType::SE2;
  v.id = 3;
  v.value = {0.1 + 0.2, 1.0 / 3.0, -2.0 / 3.0};
  ds.poses.push_back(v);
  const test::ScratchFile file(".g2o");
  writeG2oVertices(file.path(), ds);
  EXPECT_EQ(test::readText(file.path()),
            "VERTEX_SE2 3 0.30000000000000004 0.3333333333333333 -0.6666666666666666\n");
}

TEST(WriteVertices, IoFailureIsADatasetError) {
  const std::string path =
      (std::filesystem::temp_directory_path() / "no-such-dir-loopd" / "x.g2o").string();
  try {
    writeG2oVertices(path, Dataset{});
    FAIL();
  } catch (const DatasetError& e) {
    EXPECT_EQ(e.line(), 0);
    EXPECT_EQ(e.reason(), "No such file or directory");
  }
}

}  // namespace
}  // namespace loopd::io
