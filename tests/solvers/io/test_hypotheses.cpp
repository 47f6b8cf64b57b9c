// `HYPOTHESES k [null]` groups in g2o files: parsed into Dataset::hypotheses, written back,
// turned into the problem's ambiguous groups and scheduled once every key exists.
#include <gtest/gtest.h>

#include "io_test_util.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/io/estimate_writer.h"
#include "solvers/problem/incremental_schedule.h"
#include "solvers/problem/pose_graph_problem.h"

namespace loopd::io {
namespace {

std::string vertices(int n) {
  std::string s;
  for (int i = 0; i < n; ++i)
    s += "VERTEX_SE2 " + std::to_string(i) + " " + std::to_string(i) + " 0 0\n";
  return s;
}
std::string edge(int a, int b) {
  return "EDGE_SE2 " + std::to_string(a) + " " + std::to_string(b) + " 1 0 0 1 0 0 1 0 1\n";
}
std::string odometry(int n) {
  std::string s;
  for (int i = 0; i + 1 < n; ++i) s += edge(i, i + 1);
  return s;
}

Dataset read(const std::string& content) {
  const test::ScratchFile file(content, ".g2o");
  return readDataset(file.path());
}

void expectError(const std::string& content, int line, const std::string& reason) {
  const test::ScratchFile file(content, ".g2o");
  try {
    readDataset(file.path());
    ADD_FAILURE() << "no error for:\n" << content;
  } catch (const DatasetError& e) {
    EXPECT_EQ(e.line(), line) << e.what();
    EXPECT_NE(e.reason().find(reason), std::string::npos) << e.reason();
  }
}

TEST(Hypotheses, GroupsNameTheirEdges) {
  const Dataset d = read(vertices(6) + odometry(6) + "HYPOTHESES 3 null\n" + edge(5, 0) +
                         edge(5, 1) + edge(4, 0) + "HYPOTHESES 2\n" + edge(3, 0) + edge(3, 1));
  ASSERT_EQ(d.hypotheses.size(), 2u);
  EXPECT_EQ(d.hypotheses[0].firstEdge, 5);
  EXPECT_EQ(d.hypotheses[0].count, 3);
  EXPECT_TRUE(d.hypotheses[0].null);
  EXPECT_EQ(d.hypotheses[0].line, 12);
  EXPECT_EQ(d.hypotheses[1].firstEdge, 8);
  EXPECT_FALSE(d.hypotheses[1].null);
  EXPECT_EQ(d.edges.size(), 10u);
}

TEST(Hypotheses, MalformedGroupsAreRefusedWithTheirLine) {
  const std::string head = vertices(4) + odometry(4);  // lines 1..7
  expectError(head + "HYPOTHESES 2\n" + edge(3, 0), 8, "file ends 1 short");
  expectError(head + "HYPOTHESES 2\n" + edge(3, 0) + "VERTEX_SE2 9 0 0 0\n", 10, "1 are missing");
  expectError(head + "HYPOTHESES 2\n" + edge(3, 0) + "HYPOTHESES 2\n", 10, "1 are missing");
  expectError(head + "HYPOTHESES 0\n", 8, "at least one alternative");
  expectError(head + "HYPOTHESES 1\n" + edge(3, 0), 8, "ordinary edge");
  expectError(head + "HYPOTHESES 2 maybe\n", 8, "expected 'null'");
  expectError(head + "HYPOTHESES 2 null 3\n", 8, "a count and an optional 'null'");
  expectError(head + "HYPOTHESES x\n", 8, "");
  expectError(head + "HYPOTHESES 2\n" + edge(3, 0) + "EDGE_SE2_XY 3 0 1 0 1 0 1\n", 10, "one type");
  expectError("HYPOTHESES 2\n" + edge(1, 3) + edge(1, 2) + odometry(4), 1, "vertex lines");
}

TEST(Hypotheses, WriterRoundTrip) {
  const Dataset d = read(vertices(6) + odometry(6) + "HYPOTHESES 3 null\n" + edge(5, 0) +
                         edge(5, 1) + edge(4, 0) + edge(5, 2));
  const test::ScratchFile out(".g2o");
  writeG2oGraph(out.path(), d);
  const Dataset back = readDataset(out.path());
  test::expectSameGraph(d, back);
  ASSERT_EQ(back.hypotheses.size(), 1u);
  EXPECT_EQ(back.hypotheses[0].firstEdge, d.hypotheses[0].firstEdge);
  EXPECT_EQ(back.hypotheses[0].count, 3);
  EXPECT_TRUE(back.hypotheses[0].null);
}

TEST(Hypotheses, ProblemAndScheduleKeepGroupsApart) {
  // The group joins at pose 5, its latest key, even though two alternatives end earlier; an
  // alternative between consecutive poses is still a loop closure, never trusted odometry.
  const Dataset d =
      read(vertices(6) + odometry(6) + "HYPOTHESES 3\n" + edge(3, 0) + edge(5, 1) + edge(2, 3));
  const PoseGraphProblem p = buildProblem(d);
  ASSERT_EQ(p.ambiguous.size(), 1u);
  EXPECT_EQ(p.ambiguous[0].factors, (std::vector<int>{5, 6, 7}));
  EXPECT_EQ(p.graph[7]->role(), FactorRole::LoopClosure);
  const auto steps = incrementalSchedule(p);
  for (size_t i = 0; i < steps.size(); ++i) {
    for (int f : steps[i].factors) EXPECT_LT(f, 5);
    EXPECT_EQ(steps[i].groups.empty(), i != 5) << "step " << i;
  }
  const AmbiguousFactor a = ambiguousFactor(p, 0);
  EXPECT_EQ(a.id, 0u);
  EXPECT_FALSE(a.nullHypothesis);
  ASSERT_EQ(a.alternatives.size(), 3u);
  EXPECT_EQ(a.alternatives[1]->id(), 6u);
}

TEST(Hypotheses, WholeProblemUpdateCarriesGroupsOnce) {
  // Edges 0-4 odometry, 5-6 the group, 7 an ordinary closure after it.
  const Dataset d = read(vertices(6) + odometry(6) + "HYPOTHESES 2 null\n" + edge(5, 0) +
                         edge(4, 1) + edge(3, 0));
  const PoseGraphProblem p = buildProblem(d);
  const BackendUpdate u = wholeProblemUpdate(p);
  std::vector<FactorId> plain;
  for (const FactorPtr& f : u.factors) plain.push_back(f->id());
  EXPECT_EQ(plain, (std::vector<FactorId>{0, 1, 2, 3, 4, 7}));
  ASSERT_EQ(u.ambiguous.size(), 1u);
  EXPECT_TRUE(u.ambiguous[0].nullHypothesis);
  ASSERT_EQ(u.ambiguous[0].alternatives.size(), 2u);
  EXPECT_EQ(u.ambiguous[0].alternatives[0]->id(), 5u);
  EXPECT_EQ(u.initial.size(), 6);
  EXPECT_TRUE(u.removals.empty());
}

}  // namespace
}  // namespace loopd::io
