// The command-line tools refusing what they cannot do right: failed writes (a full disk),
// inputs that are not what they claim (loopd-eval), malformed numbers (loopd-feed) and options
// that do not apply (loopd-outliers). Each is an error with a message naming the file or the
// option, never a result.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "solvers/io/dataset_reader.h"
#include "tools/common/cli.h"
#include "tools/common/json_writer.h"
#include "tools/loopd-eval/json_input.h"
#include "tools/loopd-eval/trajectory_metrics.h"
#include "tools/loopd-outliers/outlier_generator.h"

namespace loopd::tools {
namespace {

const std::string kDatasets = LOOPD_DATASETS_DIR;
const std::string kBin = LOOPD_BINARY_DIR;
const std::string kEval = kBin + "/tools/loopd-eval";
const std::string kOutliers = kBin + "/tools/loopd-outliers";
const std::string kFeed = kBin + "/tools/loopd-feed";
const std::string kSolve = kBin + "/tools/loopd-solve";

// A scratch path of the running test's own (ctest may run the tests side by side).
std::string tmp(const std::string& name) {
  const ::testing::TestInfo* t = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::string test = t ? std::string(t->test_suite_name()) + "." + t->name() : "suite";
  return ::testing::TempDir() + "/tool_errors_" + test + "_" + name;
}

struct Outcome {
  int status = -1;  // exit status (128 + signal when killed)
  std::string out, err;
};

// Runs a shell command with stdout and stderr captured.
Outcome run(const std::string& cmd) {
  const std::string out = tmp("stdout.txt"), err = tmp("stderr.txt");
  const int s = std::system((cmd + " > " + out + " 2> " + err).c_str());
  Outcome r;
  r.status = WIFEXITED(s) ? WEXITSTATUS(s) : 128 + WTERMSIG(s);
  r.out = readTextFile(out);
  r.err = readTextFile(err);
  return r;
}

void write(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

bool haveDevFull() { return access("/dev/full", W_OK) == 0; }

// ---- 1. A failed final write (here a full disk) is exit status 1, naming the file. ----------

TEST(ToolErrors, JsonWriteFileChecksTheFlush) {
  if (!haveDevFull()) GTEST_SKIP() << "no /dev/full";
  JsonObject o;
  o.add("x", 1);
  try {
    o.writeFile("/dev/full");
    FAIL() << "writing to a full disk succeeded";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()).rfind("cannot write /dev/full: ", 0), 0u) << e.what();
  }
  EXPECT_THROW(writeTextFile(tmp("no/such/dir.json"), "{}"), std::runtime_error);
  writeTextFile(tmp("ok.json"), o.str());
  EXPECT_EQ(readTextFile(tmp("ok.json")), o.str());
}

TEST(ToolErrors, FullDiskIsExitStatusOne) {
  if (!haveDevFull()) GTEST_SKIP() << "no /dev/full";
  const std::string grid = kDatasets + "/tinyGrid3D.g2o";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {kOutliers + " " + grid + " --count 2 --mode random --out " + tmp("o.g2o") +
           " --truth /dev/full",
       "loopd-outliers: cannot write /dev/full: "},
      {kEval + " --reference " + grid + " --estimate " + grid + " --json /dev/full",
       "loopd-eval: cannot write /dev/full: "},
      {kFeed + " " + grid + " --quiet --log /dev/full", "loopd-feed: cannot write /dev/full: "},
      {kSolve + " " + grid + " --quiet --stats /dev/full",
       "loopd-solve: cannot write /dev/full: "}};
  for (const auto& [cmd, message] : cases) {
    const Outcome r = run(cmd);
    EXPECT_EQ(r.status, 1) << cmd << "\n" << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << cmd << "\n" << r.err;
  }
}

// ---- 2. loopd-eval: a truth or stats file must be one, and fit the graph. --------------------

class EvalInputs : public ::testing::Test {
 protected:
  void SetUp() override {
    const Outcome gen = run(kOutliers + " " + grid_ + " --count 3 --mode random --seed 2 --out " +
                            graph_ + " --truth " + truth_);
    ASSERT_EQ(gen.status, 0) << gen.err;
    outliers_ = jsonIntArray(readTextFile(truth_), "outliers");
    ASSERT_EQ(outliers_.size(), 3u);
    write(stats_,
          "{\n  \"solver\": \"x\",\n  \"rejected\": [" + std::to_string(outliers_[0]) + "]\n}\n");
  }
  // loopd-eval on tinyGrid3D with this truth and stats (and the graph).
  Outcome eval(const std::string& truth, const std::string& stats, bool graph = true) {
    return run(kEval + " --reference " + grid_ + " --estimate " + grid_ + " --truth " + truth +
               " --stats " + stats + (graph ? " --graph " + graph_ : ""));
  }
  const std::string grid_ = kDatasets + "/tinyGrid3D.g2o";
  const std::string graph_ = tmp("grid_out.g2o"), truth_ = tmp("grid_truth.json"),
                    stats_ = tmp("grid_stats.json");
  std::vector<std::int64_t> outliers_;
};

TEST_F(EvalInputs, GoodFilesAreScored) {
  const Outcome r = eval(truth_, stats_);
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("outliers 3  rejected 1  TP 1 FP 0 FN 2  precision 1.0000  recall 0.3333"),
            std::string::npos)
      << r.out;
}

TEST_F(EvalInputs, MalformedOrWrongTruthIsAnError) {
  const std::vector<std::pair<std::string, std::string>> truths = {
      {"{\"count\": 3}", "no \"outliers\" array"},
      {"garbage\n", "not a JSON object"},
      {"{\"outliers\": [\"a\"]}", "element 0 is \"a\""},
      {"{\"outliers\": [99999999999999999999]}", "does not fit a 64-bit integer"},
      {"{\"outliers\": [1,,2]}", "not JSON"},
      {"{\"outliers\": [1, 2]", "not JSON"},
      {"{\"outliers\": [1.5]}", "element 0 is 1.5"},
      {"{\"outliers\": [-1]}", "holds -1"},
      {"{\"outliers\": 3}", "not an array of integers"},
      {"{\"outliers\": [1], \"outliers\": [2]}", "duplicate key"}};
  int k = 0;
  for (const auto& [text, reason] : truths) {
    const std::string path = tmp("bad_truth" + std::to_string(k++) + ".json");
    write(path, text);
    const Outcome r = eval(path, stats_);
    EXPECT_EQ(r.status, 1) << text << "\n" << r.out << r.err;
    EXPECT_NE(r.err.find("loopd-eval: " + path + ": "), std::string::npos) << text << "\n" << r.err;
    EXPECT_NE(r.err.find(reason), std::string::npos) << text << "\n" << r.err;
    EXPECT_EQ(r.out, "") << "nothing scored";
  }
}

TEST_F(EvalInputs, SwappedFilesAreAnError) {
  Outcome r = eval(stats_, truth_);
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find(stats_ + ": no \"outliers\" array (not a loopd-outliers truth file?)"),
            std::string::npos)
      << r.err;
  r = eval(truth_, truth_);
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find(truth_ + ": no \"rejected\" array (not a loopd-solve stats file?)"),
            std::string::npos)
      << r.err;
  r = run(kEval + " --reference " + grid_ + " --estimate " + grid_ + " --stats " + stats_);
  EXPECT_EQ(r.status, 2) << "--stats without --truth scores nothing";
  EXPECT_NE(r.err.find("--stats needs --truth"), std::string::npos) << r.err;
}

TEST_F(EvalInputs, TruthOfAnotherGraphIsAnError) {
  const std::string other = tmp("intel_truth.json");
  const Outcome gen =
      run(kOutliers + " " + kDatasets + "/intel.g2o --count 3 --mode random --out " +
          tmp("intel_out.g2o") + " --truth " + other);
  ASSERT_EQ(gen.status, 0) << gen.err;
  Outcome r = eval(other, stats_);
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.err.find(other + ": outlier edge "), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(graph_ + " has " + std::to_string(io::readDataset(graph_).edges.size()) +
                       " edges"),
            std::string::npos)
      << r.err;
  r = eval(other, stats_, /*graph=*/false);  // nothing to check it against
  EXPECT_EQ(r.status, 0) << r.err;
}

TEST(EvalJson, StrictIntArrays) {
  EXPECT_EQ(jsonIntArray("{\"a\": [ 1, -2 ,3], \"b\": {\"c\": [\"x\"]}, \"d\": \"[\"}", "a"),
            (std::vector<std::int64_t>{1, -2, 3}));
  EXPECT_TRUE(jsonIntArray("{\"a\": []}", "a").empty());
  EXPECT_TRUE(jsonIntArray("{\"a\": [1]}", "b").empty()) << "absent: empty";
  EXPECT_TRUE(jsonHasKey("{\"true_choice\": [0]}", "true_choice"));
  EXPECT_FALSE(jsonHasKey("{\"input\": \"true_choice\"}", "true_choice")) << "a value, not a key";
  for (const char* bad :
       {"garbage", "{\"a\": [1,,2]}", "{\"a\": [1,]}", "{\"a\": [01]}", "{\"a\": [\"1\"]}",
        "{\"a\": [1e3]}", "{\"a\": [1]} x", "{\"a\": [9223372036854775808]}", "[1]", ""})
    EXPECT_THROW(jsonIntArray(bad, "a"), std::runtime_error) << bad;
}

// ---- 3. loopd-eval: both trajectories hold the same poses, once each, all 2D or all 3D. ------

class EvalPoses : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    std::ifstream in(kDatasets + "/intel.g2o");
    for (std::string line; std::getline(in, line);)
      if (line.rfind("VERTEX_SE2 ", 0) == 0) vertices_.push_back(line);
  }
  // The intel vertex lines as a file, changed by `edit`.
  template <class Edit>
  std::string estimate(const std::string& name, Edit edit) {
    std::vector<std::string> lines = vertices_;
    edit(lines);
    std::string text;
    for (const auto& l : lines) text += l + "\n";
    write(tmp(name), text);
    return tmp(name);
  }
  Outcome eval(const std::string& est) {
    return run(kEval + " --reference " + kDatasets + "/intel.g2o --estimate " + est);
  }
  static std::vector<std::string> vertices_;
};
std::vector<std::string> EvalPoses::vertices_;

TEST_F(EvalPoses, SameFileScoresZero) {
  const Outcome r = eval(estimate("same.g2o", [](auto&) {}));
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out.rfind("poses 1728  ATE rmse ", 0), 0u) << r.out;
}

TEST_F(EvalPoses, MissingPosesAreAnError) {
  const std::string two = estimate("two.g2o", [](auto& l) { l.resize(2); });
  Outcome r = eval(two);
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.err.find(two + " lacks 1726 of the 1728 poses of " + kDatasets +
                       "/intel.g2o (first missing: id 2)"),
            std::string::npos)
      << r.err;
  const std::string holed = estimate("holed.g2o", [](auto& l) { l.erase(l.begin() + 700); });
  r = eval(holed);
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.err.find("lacks 1 of the 1728 poses"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("(first missing: id 700)"), std::string::npos) << r.err;
}

TEST_F(EvalPoses, AnotherDatasetIsAnError) {
  // Another dataset's estimate holding intel's ids and more (as manhattan's 3500 poses do):
  // every one of intel's would be "shared".
  const std::string bigger = estimate("bigger.g2o", [](auto& l) {
    for (int k = 0; k < 1772; ++k)
      l.push_back("VERTEX_SE2 " + std::to_string(1728 + k) + " 1 2 0.5");
  });
  Outcome r = eval(bigger);
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(
      r.err.find(bigger + " has 1772 poses " + kDatasets + "/intel.g2o lacks (first: id 1728)"),
      std::string::npos)
      << r.err;
  // manhattan.g2o itself has edges only: no pose of intel's at all.
  r = eval(kDatasets + "/manhattan.g2o");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.err.find("manhattan.g2o lacks 1728 of the 1728 poses"), std::string::npos) << r.err;
}

TEST_F(EvalPoses, DuplicateIdIsAnErrorAtItsLine) {
  const std::string dup = estimate("dup.g2o", [](auto& l) { l.push_back(l[4]); });
  const Outcome r = eval(dup);
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.err.find(dup + ":1729: pose id 4 given twice (first on line 5)"), std::string::npos)
      << r.err;
  // Victoria Park's landmarks and poses have ids of their own: not duplicates.
  write(tmp("vp.g2o"), "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_XY 0 5 5\n");
  EXPECT_NO_THROW(readVertices(tmp("vp.g2o")));
  write(tmp("vp2.g2o"), "VERTEX_SE2 0 0 0 0\nVERTEX_XY 3 5 5\nVERTEX_XY 3 5 6\n");
  EXPECT_THROW(readVertices(tmp("vp2.g2o")), std::runtime_error);
}

TEST_F(EvalPoses, TwoAndThreeDimensionsMixedAnywhereIsAnError) {
  // Pose 100, not the first shared one, is 3D in the estimate.
  const std::string mixed =
      estimate("mixed.g2o", [](auto& l) { l[100] = "VERTEX_SE3:QUAT 100 1 2 0 0 0 0 1"; });
  Outcome r = eval(mixed);
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.err.find("mix 2D and 3D poses: pose 100 is 2D in"), std::string::npos) << r.err;
  // The same within the reference (and the estimate): one file mixing both.
  r = run(kEval + " --reference " + mixed + " --estimate " + mixed);
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.err.find(mixed + " mixes 2D and 3D poses"), std::string::npos) << r.err;
}

// ---- 4. loopd-eval --quiet: no summary, --json still written. -------------------------------

TEST(EvalQuiet, NoSummaryButJson) {
  const std::string grid = kDatasets + "/tinyGrid3D.g2o", json = tmp("quiet.json");
  std::remove(json.c_str());
  Outcome r = run(kEval + " --reference " + grid + " --estimate " + grid + " --graph " + grid +
                  " --quiet --json " + json);
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(r.err, "");
  const std::string j = readTextFile(json);
  EXPECT_EQ(jsonNumber(j, "poses", -1), 9);
  EXPECT_NE(j.find("\"inlier_chi2\": "), std::string::npos) << j;
  r = run(kEval + " --reference " + grid + " --estimate " + grid + " -q");
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, "");
  r = run(kEval + " --reference " + grid + " --estimate " + grid);
  EXPECT_EQ(r.out.rfind("poses 9  ATE rmse ", 0), 0u) << r.out;
}

// ---- 5. loopd-feed: numbers whole, finite and in range, else a usage error naming the flag. --

TEST(StrictNumbers, ParseFlags) {
  EXPECT_EQ(parseIntFlag("--n", "42", 1, 100), 42);
  EXPECT_EQ(parseIntFlag("--n", "-3", -5, 5), -3);
  EXPECT_DOUBLE_EQ(parseNumberFlag("--x", "2.5", 0, 10), 2.5);
  EXPECT_DOUBLE_EQ(parseNumberFlag("--x", "1e2", 0, 1000), 100.0);
  for (const char* bad :
       {"", "2x", "5abc", " 5", "abc", "-3", "0", "101", "1e2", "2.0", "99999999999999999999999"})
    EXPECT_THROW(parseIntFlag("--n", bad, 1, 100), std::invalid_argument) << bad;
  for (const char* bad : {"", "nan", "inf", "-inf", "1e999", "-1", "11", "1x", " 1"})
    EXPECT_THROW(parseNumberFlag("--x", bad, 0, 10), std::invalid_argument) << bad;
  try {
    parseIntFlag("--robots", "2x", 1, 1000);
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(), "--robots takes an integer in [1, 1000], got '2x'");
  }
}

TEST(FeedArguments, MalformedNumbersAreUsageErrors) {
  const std::string feed =
      kFeed + " " + kDatasets + "/tinyGrid3D.g2o --quiet --log " + tmp("feed.lcmlog") + " ";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"--robots 2x", "--robots"},
      {"--robots abc", "--robots"},
      {"--robots 0", "--robots"},
      {"--robots 1001", "--robots"},
      {"--poses 5abc", "--poses"},
      {"--poses -3", "--poses"},
      {"--poses 0", "--poses"},
      {"--rate nan", "--rate"},
      {"--rate 1e999", "--rate"},
      {"--rate -1", "--rate"},
      {"--rate 2hz", "--rate"},
      {"--rate inf", "--rate"},
      {"--rate 1e-300", "--rate"},
      {"--landmark-owner -1", "--landmark-owner"},
      {"--landmark-owner x", "--landmark-owner"},
      {"--landmark-namespace -1", "--landmark-namespace"},
      {"--landmark-namespace 1000000001", "--landmark-namespace"}};
  for (const auto& [args, flag] : cases) {
    const Outcome r = run(feed + args);
    EXPECT_EQ(r.status, 2) << args << "\n" << r.err;
    EXPECT_EQ(r.err.rfind("loopd-feed: " + flag + " takes ", 0), 0u) << args << "\n" << r.err;
  }
  const Outcome ok = run(feed + "--robots 2 --poses 5 --rate 0");
  EXPECT_EQ(ok.status, 0) << ok.err;
  // The owner must be one of the robots.
  const Outcome owner = run(feed + "--robots 2 --landmark-owner 2");
  EXPECT_EQ(owner.status, 2) << owner.err;
  EXPECT_EQ(owner.err.rfind("loopd-feed: --landmark-owner 2 needs --robots above it", 0), 0u)
      << owner.err;
  EXPECT_EQ(run(feed + "--robots 2 --landmark-owner 1").status, 0);
  // A namespace is not one of them; and one of the two flags, once.
  const Outcome ns = run(feed + "--robots 2 --landmark-namespace 1");
  EXPECT_EQ(ns.status, 2) << ns.err;
  EXPECT_EQ(ns.err.rfind("loopd-feed: --landmark-namespace 1 is a robot fed", 0), 0u) << ns.err;
  const Outcome both = run(feed + "--robots 2 --landmark-owner 1 --landmark-namespace 5");
  EXPECT_EQ(both.status, 2) << both.err;
  EXPECT_EQ(run(feed + "--robots 2 --landmark-namespace 100").status, 0);
  const Outcome slow = run(feed + "--poses 3 --rate 1e6");  // a log does not wait
  EXPECT_EQ(slow.status, 0) << slow.err;
}

// ---- 6. loopd-outliers: --local-groups explained, groups that fit, options that apply. -------

TEST(OutliersArguments, HelpExplainsLocalGroups) {
  const Outcome r = run(kOutliers + " --help");
  EXPECT_EQ(r.status, 0);
  // Beyond the usage line: what it does.
  const size_t usage = r.out.find("[--local-groups]");
  ASSERT_NE(usage, std::string::npos) << r.out;
  EXPECT_NE(r.out.find("--local-groups (group mode only) local", usage), std::string::npos)
      << r.out;
}

// Groups of K pairs (a + j, b + j) with b >= a + 2 fit in K + 2 poses: tinyGrid3D's 9 hold
// groups of 7 (pairs (0, 2) … (6, 8)), not of 8.
TEST(OutliersArguments, GroupsThatFitAreMade) {
  const std::string graph = tmp("grid7.g2o"), truth = tmp("grid7.json");
  const std::string base = kOutliers + " " + kDatasets + "/tinyGrid3D.g2o --mode group --out " +
                           graph + " --truth " + truth;
  Outcome r = run(base + " --count 7 --group-size 7");
  ASSERT_EQ(r.status, 0) << r.err;
  const io::Dataset g = io::readDataset(graph);
  const std::vector<std::int64_t> out = jsonIntArray(readTextFile(truth), "outliers");
  ASSERT_EQ(out.size(), 7u);
  for (size_t j = 0; j < out.size(); ++j) {
    const io::Edge& e = g.edges[static_cast<size_t>(out[j])];
    EXPECT_EQ(e.from, static_cast<std::int64_t>(j));
    EXPECT_EQ(e.to, static_cast<std::int64_t>(j) + 2);
  }
  r = run(base + " --count 7 --group-size 8");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("too few poses for outliers: 9, groups of 8 need 10"), std::string::npos)
      << r.err;

  // The smallest graphs: 3 poses for a single pair.
  const io::Dataset grid = io::readDataset(kDatasets + "/tinyGrid3D.g2o");
  OutlierOptions o;
  o.count = 4;
  o.mode = OutlierMode::Group;
  o.groupSize = 7;
  EXPECT_NO_THROW(addOutliers(grid, o));
  o.groupSize = 8;
  EXPECT_THROW(addOutliers(grid, o), std::invalid_argument);
  io::Dataset three = grid;
  three.poses.resize(3);
  std::vector<io::Edge> kept;
  for (const io::Edge& e : three.edges)
    if (e.from < 3 && e.to < 3) kept.push_back(e);
  three.edges = kept;
  ASSERT_FALSE(three.edges.empty());
  for (OutlierMode m : {OutlierMode::Random, OutlierMode::Local}) {
    o.mode = m;
    const OutlierResult res = addOutliers(three, o);
    for (int i : res.outliers) {
      EXPECT_EQ(res.graph.edges[static_cast<size_t>(i)].from, 0);
      EXPECT_EQ(res.graph.edges[static_cast<size_t>(i)].to, 2);
    }
  }
  three.poses.resize(2);
  EXPECT_THROW(addOutliers(three, o), std::invalid_argument);
}

TEST(OutliersArguments, OptionsThatDoNotApplyAreUsageErrors) {
  const std::string base = kOutliers + " " + kDatasets + "/intel.g2o --out " + tmp("opt.g2o") +
                           " --truth " + tmp("opt.json") + " ";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"--count 3 --mode random --landmarks", "--landmarks needs --ambiguous"},
      {"--count 3 --mode random --null", "--null needs --ambiguous"},
      {"--count 3 --mode local --alternatives 4", "--alternatives needs --ambiguous"},
      {"--count 3 --mode group --decoys target", "--decoys needs --ambiguous"},
      {"--count 3 --mode local --local-groups", "--local-groups needs --mode group"},
      {"--count 3 --mode random --local-groups", "--local-groups needs --mode group"},
      {"--ambiguous 2 --group-size 3", "--group-size does not combine with --ambiguous"},
      {"--ambiguous 2 --local-groups", "--local-groups does not combine with --ambiguous"}};
  for (const auto& [args, message] : cases) {
    const Outcome r = run(base + args);
    EXPECT_EQ(r.status, 2) << args << "\n" << r.err;
    EXPECT_EQ(r.err.rfind("loopd-outliers: " + message + "\n", 0), 0u) << args << "\n" << r.err;
  }
  // What tools/compare passes to every mode stays accepted.
  for (const std::string args : {"--count 3 --mode random --group-size 10 --window 30",
                                 "--count 3 --mode local --group-size 10",
                                 "--count 4 --mode group --group-size 2 --local-groups --window 9",
                                 "--ambiguous 2 --null --decoys measurement --landmarks --window 5"
                                 " --alternatives 2"}) {
    const std::string in = args.find("--landmarks") != std::string::npos
                               ? kDatasets + "/victoria_park.txt"
                               : kDatasets + "/intel.g2o";
    const Outcome r = run(kOutliers + " " + in + " --out " + tmp("opt.g2o") + " --truth " +
                          tmp("opt.json") + " " + args);
    EXPECT_EQ(r.status, 0) << args << "\n" << r.err;
  }
}

}  // namespace
}  // namespace loopd::tools
