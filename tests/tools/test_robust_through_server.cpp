// Issue 5's "the same through the server": intel with wrong loop closures from loopd-outliers
// (random, local, groups), fed by loopd-feed as one robot and as two interleaved robots to a
// real loopd server under each robust variant, recorded by loopd-listen (--decisions) and
// scored by loopd-eval as loopd-solve's runs are: precision and recall of the server's
// rejections and the chi2 of its estimate over the true edges against the outlier-free optimum.
#include <gtest/gtest.h>

#include <fstream>
#include <ostream>
#include <string>

#include "tests/server/live_util.h"
#include "tests/tools/feed_through_server.h"
#include "tools/loopd-eval/json_input.h"

using namespace loopd::testing_live;

namespace {

/// intel's outlier-free optimum (loopd-solve, once per process).
const std::string& intelOptimum() {
  static const std::string path = [] {
    const std::string out = tmp("intel_opt.g2o");
    EXPECT_EQ(runTool({kSolve, kData + "/intel.g2o", "--out", out, "--quiet"}, tmp("opt.log")), 0);
    return out;
  }();
  return path;
}

struct Scores {
  double precision = NAN, recall = NAN, inlierChi2 = NAN;
  long long poses = -1;
};

struct Case {
  std::string variant, mode;
  int robots;
};

// Without it ctest lists each case's parameter as a byte dump.
void PrintTo(const Case& c, std::ostream* os) {
  *os << c.variant << ' ' << c.mode << ' ' << c.robots << " robot(s)";
}

/// intel + 30 wrong closures of `mode` (seed 42, groups of 5) through a server running
/// `variant`, fed as `robots` robots (interleaved), scored by loopd-eval.
Scores runThroughServer(const Case& c, std::string& said) {
  const std::string name = c.variant + "_" + c.mode + "_" + std::to_string(c.robots);
  const std::string graph = tmp(c.mode + "_30.g2o"), truth = tmp(c.mode + "_30_truth.json");
  if (!std::ifstream(graph))
    EXPECT_EQ(
        runTool({kBin + "/tools/loopd-outliers", kData + "/intel.g2o", "--count", "30", "--mode",
                 c.mode, "--group-size", "5", "--seed", "42", "--out", graph, "--truth", truth},
                tmp(name + "_outliers.log")),
        0);
  std::vector<std::string> feed = {"--robots", std::to_string(c.robots), "--rate", "0"};
  if (c.robots > 1) feed.push_back("--interleave");
  std::string log;
  const std::string decisions = tmp(name + "_decisions.json");
  feedThroughServer(name, graph, 1728, feed, said, log, {"--solver", c.variant},
                    {"--decisions", decisions});
  const std::string eval = tmp(name + "_eval.json");
  EXPECT_EQ(runTool({kBin + "/tools/loopd-eval", "--reference", intelOptimum(), "--estimate",
                     tmp(name + ".g2o"), "--truth", truth, "--graph", graph, "--stats", decisions,
                     "--json", eval, "--quiet"},
                    tmp(name + "_eval.log")),
            0)
      << readText(tmp(name + "_eval.log"));
  const std::string j = readText(eval);
  Scores s;
  s.precision = loopd::tools::jsonNumber(j, "precision", NAN);
  s.recall = loopd::tools::jsonNumber(j, "recall", NAN);
  s.inlierChi2 = loopd::tools::jsonNumber(j, "inlier_chi2", NAN);
  s.poses = static_cast<long long>(loopd::tools::jsonNumber(j, "poses", -1));
  return s;
}

constexpr double kIntelOptimum = 45.0046959;  // chi2 of intel's outlier-free optimum

class RobustThroughServer : public ::testing::TestWithParam<Case> {};

// The good variants reject every wrong closure and land on the outlier-free optimum, as
// loopd-solve does, with one robot and with two.
TEST_P(RobustThroughServer, RejectsTheWrongClosuresAndReachesTheOptimum) {
  const Case& c = GetParam();
  std::string said;
  const Scores s = runThroughServer(c, said);
  std::printf(
      "[through server] %-7s %-6s %d robot(s): precision %.3f recall %.3f chi2(true) %.6g\n",
      c.variant.c_str(), c.mode.c_str(), c.robots, s.precision, s.recall, s.inlierChi2);
  EXPECT_NE(said.find("1728 batches accepted, 0 duplicate, 0 rejected, 0 expired"),
            std::string::npos)
      << said;
  EXPECT_EQ(s.poses, 1728);
  EXPECT_GE(s.recall, 0.99);
  EXPECT_GE(s.precision, 0.99);
  EXPECT_NEAR(s.inlierChi2, kIntelOptimum, 0.01 * kIntelOptimum);
}

std::vector<Case> goodCases() {
  std::vector<Case> out;
  for (const char* v : {"risam", "gnc-tls"})
    for (const char* m : {"random", "local", "group"})
      for (int r : {1, 2}) out.push_back({v, m, r});
  return out;
}

INSTANTIATE_TEST_SUITE_P(Good, RobustThroughServer, ::testing::ValuesIn(goodCases()),
                         [](const auto& info) {
                           std::string n = info.param.variant + "_" + info.param.mode + "_" +
                                           std::to_string(info.param.robots) + "robots";
                           for (char& ch : n)
                             if (!isalnum(static_cast<unsigned char>(ch))) ch = '_';
                           return n;
                         });

// Switchable constraints on two robots: an inter-robot closure is a factor over two anchors and
// two poses, and its switch made a fifth key, beyond what a factor held (kMaxFactorKeys was 4).
// The server refused every batch carrying one (627 of 1728 in this run, 583 poses lost); now
// the two robots end as one robot does (sc's own +12.7% on intel, four true closures
// switched off, is its known limit with the literature's prior).
TEST(RobustThroughServer, SwitchableConstraintsTakeInterRobotClosures) {
  std::string saidOne, saidTwo;
  const Scores one = runThroughServer({"sc", "random", 1}, saidOne);
  const Scores two = runThroughServer({"sc", "random", 2}, saidTwo);
  EXPECT_NE(saidTwo.find("1728 batches accepted, 0 duplicate, 0 rejected, 0 expired"),
            std::string::npos)
      << saidTwo;
  EXPECT_EQ(two.poses, 1728);
  EXPECT_EQ(two.recall, 1.0);
  EXPECT_NEAR(two.precision, one.precision, 0.05);
  EXPECT_NEAR(two.inlierChi2, one.inlierChi2, 0.05 * one.inlierChi2);
}

}  // namespace
