// command_t through the engine (driven directly, no LCM): arguments and keys refused with the
// documented codes, SAVE_SNAPSHOT's g2o file for several robots, the command channel's
// decode errors in the log; and loopd's numeric and --log-level flags.
#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "client/factor_publisher.h"
#include "loopd/command_t.hpp"
#include "loopd/covariance_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "loopd/status_t.hpp"
#include "server/engine.h"
#include "server/server_config.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/problem/pose_graph_problem.h"
#include "tests/server/engine_harness.h"
#include "tests/server/live_util.h"
#include "tests/server/wire_encode.h"

using namespace loopd;
using namespace loopd::server;
using client::KeyRef;
using client::Pose2;
using C = loopd::command_t;
using E = loopd::error_t;

namespace {

using test::between2;

factor_t landmark2(std::int64_t id, int r, std::int64_t pose, int lr, std::int64_t l, double x,
                   double y) {
  Eigen::Matrix2d info;
  info << 40, 3, 3, 20;
  factor_t f = client::landmarkFactor(KeyRef::pose(r, pose), KeyRef::point(lr, l),
                                      Eigen::Vector2d(x, y), info);
  f.id = id;
  return f;
}

using test::batch;

loopd::key_t wkey(int r, std::int64_t i, std::int8_t kind = loopd::key_t::POSE) {
  loopd::key_t k{};
  k.robot = r;
  k.kind = kind;
  k.index = i;
  return k;
}

// Everything the engine logs while it lives (spdlog's default logger gets a second sink).
class LogCapture {
 public:
  LogCapture() : sink_(std::make_shared<spdlog::sinks::ostream_sink_mt>(text_)) {
    spdlog::default_logger()->sinks().push_back(sink_);
  }
  ~LogCapture() {
    auto& s = spdlog::default_logger()->sinks();
    s.erase(std::remove(s.begin(), s.end(), sink_), s.end());
  }
  std::string text() const { return text_.str(); }

 private:
  std::ostringstream text_;
  std::shared_ptr<spdlog::sinks::ostream_sink_mt> sink_;
};

struct Fixture : test::EngineHarness {
  std::int64_t seq0 = 0, seq1 = 0;
  explicit Fixture(const std::string& solver = "lm") : EngineHarness(solver) {}
  // Robot 0: poses 0..5; robot 1: poses 0..5 (the same indices), joined by a closure
  // r0:x5 → r1:x0.
  void twoRobots() {
    std::vector<factor_t> a, b;
    for (int i = 0; i < 5; ++i) a.push_back(between2(i, 0, i, 0, i + 1, {1, 0, 0}));
    for (int i = 0; i < 5; ++i) b.push_back(between2(i, 1, i, 1, i + 1, {0, 1, 0}));
    send(batch("a", ++seq0, a));
    send(batch("b", ++seq1, b));
    send(batch("b", ++seq1, {between2(100, 0, 5, 1, 0, {0, 2, 0}, factor_t::ROLE_LOOP_CLOSURE)}));
    ASSERT_TRUE(out.errors.empty()) << out.errors.front().reason;
    ASSERT_TRUE(engine.robotJoined(1));
  }
  // Replies with `requestId` since `mark` (counts of statuses, estimates, covariances).
  struct Mark {
    size_t errors, statuses, estimates, covariances;
  };
  Mark mark() const {
    return {out.errors.size(), out.statuses.size(), out.estimates.size(), out.covariances.size()};
  }
  int repliesSince(const Mark& m, std::int64_t requestId) const {
    int n = 0;
    for (size_t i = m.statuses; i < out.statuses.size(); ++i)
      n += out.statuses[i].request_id == requestId;
    for (size_t i = m.estimates; i < out.estimates.size(); ++i)
      n += out.estimates[i].request_id == requestId;
    for (size_t i = m.covariances; i < out.covariances.size(); ++i)
      n += out.covariances[i].request_id == requestId;
    return n;
  }
};

// A command refused: exactly one error with `code` and the request id, no reply, logged, the
// graph as it was.
void expectRefused(Fixture& f, std::int8_t cmd, const std::string& arg,
                   std::vector<loopd::key_t> keys, std::int8_t code, std::int64_t rid = 7) {
  SCOPED_TRACE("command " + std::to_string(cmd) + " '" + arg.substr(0, 40) + "' with " +
               std::to_string(keys.size()) + " keys, request " + std::to_string(rid));
  const auto m = f.mark();
  const int poses = f.poses();
  const std::string solver = f.engine.backend().name();
  LogCapture log;
  f.command(cmd, arg, std::move(keys), rid);
  ASSERT_EQ(f.out.errors.size(), m.errors + 1);
  EXPECT_EQ(f.out.errors.back().code, code) << f.out.errors.back().reason;
  EXPECT_EQ(f.out.errors.back().request_id, rid);
  EXPECT_EQ(f.out.errors.back().sender, "test");
  if (rid > 0) EXPECT_EQ(f.repliesSince(m, rid), 0);  // (0: every periodic status)
  EXPECT_EQ(f.out.covariances.size(), m.covariances);
  EXPECT_EQ(f.poses(), poses);
  EXPECT_EQ(f.engine.backend().name(), solver);
  EXPECT_NE(log.text().find("[warning]"), std::string::npos) << log.text();
}

std::set<int> robotsAnswered(const Fixture& f, size_t from, std::int64_t rid) {
  std::set<int> r;
  for (size_t i = from; i < f.out.estimates.size(); ++i)
    if (f.out.estimates[i].request_id == rid) r.insert(f.out.estimates[i].robot);
  return r;
}

// --- bug B: arguments ---------------------------------------------------------------------

TEST(EngineCommands, RequestEstimateTakesOnlyTheIdOfARobotInTheGraph) {
  Fixture f;
  f.twoRobots();
  size_t from = f.out.estimates.size();
  f.command(C::REQUEST_ESTIMATE, "", {}, 2);
  EXPECT_EQ(robotsAnswered(f, from, 2), (std::set<int>{0, 1}));
  from = f.out.estimates.size();
  f.command(C::REQUEST_ESTIMATE, "1", {}, 3);
  EXPECT_EQ(robotsAnswered(f, from, 3), (std::set<int>{1}));
  for (const std::string arg :
       {"7", "-3", "1abc", " 1", "+1", "1 ", "x", "99999999999999", "4294967297", "65536"})
    expectRefused(f, C::REQUEST_ESTIMATE, arg, {}, E::COMMAND_FAILED);
  EXPECT_TRUE(f.out.errors.back().reason.find("robot") != std::string::npos);
}

TEST(EngineCommands, CovarianceRefusesTooManyKeysAndKeysOutOfRange) {
  Fixture f;
  f.twoRobots();
  std::vector<loopd::key_t> many;
  for (int i = 0; i < 1500; ++i) many.push_back(wkey(0, i % 6));
  expectRefused(f, C::REQUEST_COVARIANCE, "marginals", many, E::LIMIT_EXCEEDED);
  many.resize(1025);
  expectRefused(f, C::REQUEST_COVARIANCE, "marginals", many, E::LIMIT_EXCEEDED);
  // 2^40 + 2 would pack to r0:x2, robot 65536 + 1 to robot 1.
  expectRefused(f, C::REQUEST_COVARIANCE, "", {wkey(0, (std::int64_t{1} << 40) + 2)},
                E::UNKNOWN_KEY);
  expectRefused(f, C::REQUEST_COVARIANCE, "", {wkey(65537, 2)}, E::UNKNOWN_KEY);
  expectRefused(f, C::REQUEST_COVARIANCE, "", {wkey(-1, 2)}, E::UNKNOWN_KEY);
  expectRefused(f, C::REQUEST_COVARIANCE, "", {wkey(0, -2)}, E::UNKNOWN_KEY);
  expectRefused(f, C::REQUEST_COVARIANCE, "", {wkey(0, 2, 2)}, E::UNKNOWN_KEY);
  expectRefused(f, C::REQUEST_COVARIANCE, "", {wkey(0, 2), wkey(0, 99)}, E::UNKNOWN_KEY);
  expectRefused(f, C::REQUEST_COVARIANCE, "bogus", {wkey(0, 2)}, E::COMMAND_FAILED);
  expectRefused(f, C::REQUEST_COVARIANCE, "", {}, E::COMMAND_FAILED);
  // At the limit: answered, 144 keys per message.
  many.resize(1024);
  const auto m = f.mark();
  f.command(C::REQUEST_COVARIANCE, "marginals", many, 8);
  EXPECT_EQ(f.out.errors.size(), m.errors);
  int keys = 0;
  for (size_t i = m.covariances; i < f.out.covariances.size(); ++i)
    keys += f.out.covariances[i].num_keys;
  EXPECT_EQ(keys, 1024);
  EXPECT_EQ(f.out.covariances.back().chunk_count, 8);
  f.command(C::REQUEST_COVARIANCE, "", {wkey(0, 2)}, 9);
  ASSERT_EQ(f.out.covariances.back().request_id, 9);
  EXPECT_EQ(f.out.covariances.back().keys[0].index, 2);
}

TEST(EngineCommands, ArgumentsBeyondTheLengthLimitAreRefused) {
  Fixture f;
  f.twoRobots();
  const std::string longArg(5000, 'x');
  for (std::int8_t c : {C::RESET, C::SWITCH_SOLVER, C::REQUEST_COVARIANCE, C::REQUEST_ESTIMATE,
                        C::SAVE_SNAPSHOT, C::REQUEST_HYPOTHESES, C::OPTIMIZE, C::REQUEST_STATUS})
    expectRefused(f, c, longArg, {}, E::LIMIT_EXCEEDED);
  expectRefused(f, C::SWITCH_SOLVER, std::string(4096, 'x'), {}, E::LIMIT_EXCEEDED);
  // 4095 characters are within the limit: refused for what they say.
  expectRefused(f, C::SWITCH_SOLVER, std::string(4095, 'x'), {}, E::COMMAND_FAILED);
  EXPECT_LE(f.out.errors.back().reason.size(), 200u);
}

TEST(EngineCommands, EveryCommandChecksItsArgumentKeysAndRequestId) {
  Fixture f;
  f.twoRobots();
  for (const std::string arg : {"0", "2x", " 3", "+3", "-1", "3.0", "99999999999"})
    expectRefused(f, C::REQUEST_HYPOTHESES, arg, {}, E::COMMAND_FAILED);
  auto m = f.mark();
  f.command(C::REQUEST_HYPOTHESES, "3", {}, 11);
  EXPECT_EQ(f.out.errors.size(), m.errors);
  EXPECT_GT(f.repliesSince(m, 11), 0);
  // Commands documented with argument "" take nothing else (RESET keeps the graph then).
  for (std::int8_t c : {C::RESET, C::OPTIMIZE, C::REQUEST_STATUS})
    expectRefused(f, c, "junk", {}, E::COMMAND_FAILED);
  EXPECT_EQ(f.poses(), 12);
  // Keys are for REQUEST_COVARIANCE only.
  for (std::int8_t c : {C::RESET, C::REQUEST_ESTIMATE, C::REQUEST_STATUS, C::OPTIMIZE})
    expectRefused(f, c, "", {wkey(0, 1)}, E::COMMAND_FAILED);
  expectRefused(f, C::SWITCH_SOLVER, "", {}, E::COMMAND_FAILED);
  expectRefused(f, C::SWITCH_SOLVER, "ISAM2", {}, E::COMMAND_FAILED);
  expectRefused(f, C::SAVE_SNAPSHOT, "", {}, E::COMMAND_FAILED);
  // request_id > 0; commands 1..8.
  expectRefused(f, C::REQUEST_STATUS, "", {}, E::INVALID_FIELD, 0);
  expectRefused(f, C::REQUEST_STATUS, "", {}, E::INVALID_FIELD, -5);
  for (std::int8_t c : {0, 9, -1}) expectRefused(f, c, "", {}, E::INVALID_FIELD);
  m = f.mark();
  f.command(C::REQUEST_STATUS, "", {}, 12);
  EXPECT_EQ(f.out.errors.size(), m.errors);
  EXPECT_EQ(f.repliesSince(m, 12), 1);
}

// --- bug C: the command channel's decode errors are logged ---------------------------------

TEST(EngineCommands, CommandChannelDecodeErrorsAreLogged) {
  Fixture f;
  LogCapture log;
  status_t s{};
  s.solver = "x";
  f.engine.post({"T_COMMAND", test::encode(s)});
  f.engine.step();
  ASSERT_FALSE(f.out.errors.empty());
  EXPECT_EQ(f.out.errors.back().code, E::WRONG_FINGERPRINT);
  EXPECT_NE(log.text().find("[warning] T_COMMAND: fingerprint does not match command_t (it is a "
                            "status_t)"),
            std::string::npos)
      << log.text();
  command_t c{};
  c.sender = "test";
  c.request_id = 1;
  c.command = C::REQUEST_STATUS;
  auto bytes = test::encode(c);
  bytes.resize(bytes.size() - 2);
  f.engine.post({"T_COMMAND", bytes});
  f.engine.step();
  EXPECT_EQ(f.out.errors.back().code, E::DECODE_FAILED);
  EXPECT_NE(log.text().find("[warning] T_COMMAND: command_t does not decode"), std::string::npos)
      << log.text();
  bytes = test::encode(c);
  bytes.push_back(0);
  f.engine.post({"T_COMMAND", bytes});
  f.engine.step();
  EXPECT_EQ(f.out.errors.back().code, E::DECODE_FAILED);
  EXPECT_NE(log.text().find("[warning] T_COMMAND: command_t followed by 1 trailing bytes"),
            std::string::npos)
      << log.text();
}

// --- bug A: SAVE_SNAPSHOT -----------------------------------------------------------------

// Published (common-frame) values per robot: index → values, for poses and landmarks.
struct Published {
  std::map<std::pair<int, std::int64_t>, std::vector<double>> poses, landmarks;
};
Published published(const Fixture& f, std::int64_t rid) {
  Published p;
  for (const auto& e : f.out.estimates) {
    if (e.request_id != rid) continue;
    for (int i = 0; i < e.num_poses; ++i) p.poses[{e.robot, e.pose_indices[i]}] = e.poses[i];
    for (int i = 0; i < e.num_landmarks; ++i)
      p.landmarks[{e.robot, e.landmark_indices[i]}] = e.landmarks[i];
  }
  return p;
}

std::string fileText(const std::string& path) {
  std::stringstream s;
  s << std::ifstream(path).rdbuf();
  return s.str();
}

// Two robots with pose indices 0..3 and 10..13, a landmark each (robot 0's 3, robot 1's 7),
// joined: robot 0's pose 0 is 10 m behind robot 1's pose 10 in y.
void twoRobotsWithLandmarks(Fixture& f) {
  std::vector<factor_t> a, b;
  for (int i = 0; i < 3; ++i) a.push_back(between2(i, 0, i, 0, i + 1, {1, 0, 0.1}));
  a.push_back(landmark2(60, 0, 1, 0, 3, 0, 1));
  for (int i = 0; i < 3; ++i) b.push_back(between2(i, 1, 10 + i, 1, 11 + i, {1, 0, -0.1}));
  b.push_back(landmark2(50, 1, 10, 1, 7, 0, 2));
  f.send(batch("a", ++f.seq0, a));
  f.send(batch("b", ++f.seq1, b));
  // Joined, plus a closure and a sighting that do not quite agree (chi2 > 0).
  f.send(batch("b", ++f.seq1,
               {between2(100, 1, 10, 0, 0, {0, -10, 0}, factor_t::ROLE_LOOP_CLOSURE),
                between2(101, 1, 13, 0, 3, {2.6, -9.1, 0.5}, factor_t::ROLE_LOOP_CLOSURE),
                landmark2(102, 1, 12, 1, 7, -2.3, 1.7)}));
  ASSERT_TRUE(f.out.errors.empty()) << f.out.errors.front().reason;
  f.command(C::OPTIMIZE, "", {}, 1);
}

TEST(EngineCommands, SnapshotOfSeveralRobotsReadsBackAsTheSameGraph) {
  Fixture f;
  twoRobotsWithLandmarks(f);
  ASSERT_TRUE(f.engine.robotJoined(0) && f.engine.robotJoined(1));
  f.command(C::REQUEST_ESTIMATE, "", {}, 5);
  const Published pub = published(f, 5);
  ASSERT_EQ(pub.poses.size(), 8u);
  ASSERT_EQ(pub.landmarks.size(), 2u);
  const std::string path = testing_live::tmp("snap2.g2o");
  const auto m = f.mark();
  f.command(C::SAVE_SNAPSHOT, path, {}, 6);
  ASSERT_EQ(f.out.errors.size(), m.errors) << f.out.errors.back().reason;
  EXPECT_EQ(f.repliesSince(m, 6), 1);

  io::Dataset ds;
  ASSERT_NO_THROW(ds = io::readDataset(path)) << fileText(path);
  // Ids: robot 0's poses 0..3 → 0..3; robot 1's poses (indices ≤ 13) from 4: 14..17;
  // landmarks after every pose: robot 0's (≤ 3) from 18, robot 1's (≤ 7) from 22.
  auto id = [](bool landmark, int robot, std::int64_t index) -> std::int64_t {
    const std::int64_t first[2][2] = {{0, 4}, {18, 22}};
    return first[landmark][robot] + index;
  };
  const std::string text = fileText(path);
  EXPECT_NE(text.find("# robot 0 poses: id = 0 + index\n# robot 1 poses: id = 4 + index\n"
                      "# robot 0 landmarks: id = 18 + index\n"
                      "# robot 1 landmarks: id = 22 + index\n"),
            std::string::npos)
      << text;
  ASSERT_EQ(ds.poses.size(), 8u);
  ASSERT_EQ(ds.landmarks.size(), 2u);
  std::map<std::int64_t, std::vector<double>> file;
  for (const auto& v : ds.poses) file[v.id] = {v.value[0], v.value[1], v.value[2]};
  for (const auto& v : ds.landmarks) file[v.id] = {v.value[0], v.value[1]};
  ASSERT_EQ(file.size(), 10u);  // unique ids
  // Every value as published (common frame), landmarks included.
  for (const auto& [k, v] : pub.poses) {
    const auto& w = file.at(id(false, k.first, k.second));
    for (size_t i = 0; i < 3; ++i) EXPECT_NEAR(w[i], v[i], 1e-12) << "pose " << k.second;
  }
  for (const auto& [k, v] : pub.landmarks) {
    const auto& w = file.at(id(true, k.first, k.second));
    for (size_t i = 0; i < 2; ++i) EXPECT_NEAR(w[i], v[i], 1e-12) << "landmark " << k.second;
  }
  // One frame: robot 1's landmark 7 is 2 m ahead of its pose 10 (heading ≈ 0), robot 0's
  // pose 0 10 m behind it.
  const auto& x10 = file.at(id(false, 1, 10));
  EXPECT_NEAR(file.at(id(true, 1, 7))[0], x10[0], 0.1);
  EXPECT_NEAR(file.at(id(true, 1, 7))[1], x10[1] + 2, 0.1);
  EXPECT_NEAR(file.at(id(false, 0, 0))[1], x10[1] - 10, 0.1);
  // Every factor the senders sent is an edge (no priors among them): 6 odometry, 2
  // inter-robot closures, 3 sightings; and at the file's values its chi2 is the server's.
  EXPECT_EQ(ds.edges.size(), 11u);
  int inter = 0;
  for (const auto& e : ds.edges) inter += io::isBetween(e.type) && (e.from < 4) != (e.to < 4);
  EXPECT_EQ(inter, 2);
  const PoseGraphProblem p = buildProblem(ds);
  const double serverChi2 = f.engine.backend().chi2();
  EXPECT_GT(serverChi2, 0.1);
  EXPECT_NEAR(p.graph.chi2(p.initial), serverChi2, 1e-6 * serverChi2);

  // loopd-solve solves it to the same optimum.
  const std::string stats = testing_live::tmp("snap2.json");
  ASSERT_EQ(testing_live::runTool(
                {testing_live::kSolve, path, "--solver", "lm", "--stats", stats, "--quiet"},
                testing_live::tmp("solve.log")),
            0)
      << fileText(testing_live::tmp("solve.log"));
  EXPECT_NEAR(testing_live::statsChi2(stats), serverChi2, 1e-4 * serverChi2);
}

// Cross-robot sightings are written as the sightings of their common-frame landmarks; one
// kept back (its robots' frames not joined yet) is counted in the trailer, not written.
TEST(EngineCommands, SnapshotWritesCrossRobotSightingsAndCountsThoseKeptBack) {
  Fixture f;
  twoRobotsWithLandmarks(f);
  // Each robot sights the other's landmark (their frames are joined by the closures).
  f.send(batch("b", ++f.seq1, {landmark2(103, 1, 12, 0, 3, 0.4, -8.2)}));
  f.send(batch("a", ++f.seq0, {landmark2(61, 0, 2, 1, 7, -1.5, 11.2)}));
  // Robot 2, on its own, sights robot 0's landmark: kept back.
  std::int64_t seq2 = 0;
  f.send(batch("c", ++seq2, {between2(0, 2, 0, 2, 1, {1, 0, 0})}));
  f.send(batch("c", ++seq2, {landmark2(1, 2, 1, 0, 3, 2, 2)}));
  ASSERT_TRUE(f.out.errors.empty()) << f.out.errors.front().reason;
  f.command(C::OPTIMIZE, "", {}, 1);
  const std::string path = testing_live::tmp("snap_cross.g2o");
  const auto m = f.mark();
  f.command(C::SAVE_SNAPSHOT, path, {}, 6);
  ASSERT_EQ(f.out.errors.size(), m.errors) << f.out.errors.back().reason;
  const std::string text = fileText(path);
  EXPECT_NE(text.find("# not written: 1 cross-robot sightings, kept back until their robots "
                      "share a frame\n"),
            std::string::npos)
      << text;
  io::Dataset ds;
  ASSERT_NO_THROW(ds = io::readDataset(path)) << text;
  // 11 edges as before, the two cross-robot sightings and robot 2's odometry.
  EXPECT_EQ(ds.edges.size(), 14u);
  int sightings = 0;
  for (const auto& e : ds.edges) sightings += !io::isBetween(e.type);
  EXPECT_EQ(sightings, 5);
  const PoseGraphProblem p = buildProblem(ds);
  const double serverChi2 = f.engine.backend().chi2();
  EXPECT_GT(serverChi2, 0.1);
  EXPECT_NEAR(p.graph.chi2(p.initial), serverChi2, 1e-6 * serverChi2);
}

TEST(EngineCommands, SnapshotSkipsWhatG2oCannotExpressAndSaysSo) {
  Fixture f;
  std::vector<factor_t> a;
  for (int i = 0; i < 3; ++i) a.push_back(between2(i, 0, i, 0, i + 1, {1, 0, 0}));
  factor_t prior{};
  prior.id = 10;
  prior.type = factor_t::PRIOR_SE2;
  prior.role = factor_t::ROLE_PRIOR;
  prior.keys = {wkey(0, 2)};
  prior.num_keys = 1;
  prior.measurement = {2, 0, 0};
  prior.num_measurement = 3;
  prior.noise_kind = factor_t::NOISE_INFORMATION;
  prior.noise = {10, 0, 0, 10, 0, 10};
  prior.num_noise = 6;
  a.push_back(prior);
  a.push_back(client::bearingRangeFactor(KeyRef::pose(0, 1), KeyRef::point(0, 0), 0.5, 2.0,
                                         Eigen::Matrix2d::Identity() * 50));
  a.back().id = 11;
  a.push_back(landmark2(12, 0, 2, 0, 0, 0.7, 0.9));
  f.send(batch("a", ++f.seq0, a));
  ASSERT_TRUE(f.out.errors.empty()) << f.out.errors.front().reason;
  const std::string path = testing_live::tmp("snap_skip.g2o");
  LogCapture log;
  f.command(C::SAVE_SNAPSHOT, path, {}, 6);
  ASSERT_TRUE(f.out.errors.empty()) << f.out.errors.back().reason;
  EXPECT_NE(log.text().find("[warning] snapshot " + path +
                            ": not written (g2o has no form for them): 1 BearingRange2, "
                            "1 PriorSE2"),
            std::string::npos)
      << log.text();
  const std::string text = fileText(path);
  EXPECT_NE(text.find("# not written (no g2o form): 1 BearingRange2, 1 PriorSE2\n"),
            std::string::npos)
      << text;
  // One robot: its pose ids are its indices (the first line is its first pose).
  EXPECT_EQ(text.rfind("VERTEX_SE2 0 ", 0), 0u) << text;
  io::Dataset ds;
  ASSERT_NO_THROW(ds = io::readDataset(path)) << text;
  EXPECT_EQ(ds.poses.size(), 4u);
  ASSERT_EQ(ds.landmarks.size(), 1u);
  EXPECT_EQ(ds.landmarks[0].id, 4);  // after the poses' block 0..3
  EXPECT_EQ(ds.edges.size(), 4u);    // 3 odometry, 1 sighting
  // The sighting's information is the one sent.
  const auto& e = ds.edges.back();
  EXPECT_EQ(e.type, io::EdgeType::PosePoint2);
  EXPECT_EQ(e.from, 2);
  EXPECT_EQ(e.to, 4);
  EXPECT_NEAR(e.information(0, 0), 40, 1e-9);
  EXPECT_NEAR(e.information(0, 1), 3, 1e-9);
  EXPECT_NEAR(e.information(1, 1), 20, 1e-9);
  EXPECT_NEAR(e.measurement[0], 0.7, 1e-15);
}

TEST(EngineCommands, SnapshotWritesAmbiguousGroupsAsHypotheses) {
  Fixture f("mh");
  std::vector<factor_t> a;
  for (int i = 0; i < 6; ++i) a.push_back(between2(i, 0, i, 0, i + 1, {1, 0, 0}));
  factor_batch_t b = batch("a", ++f.seq0, a);
  loopd::ambiguous_factor_t g{};
  g.id = 20;
  g.mode = loopd::ambiguous_factor_t::MULTI_ASSOCIATION;
  g.alternatives = {between2(0, 0, 6, 0, 0, {-6, 0, 0}, factor_t::ROLE_LOOP_CLOSURE),
                    between2(0, 0, 6, 0, 1, {-6, 0, 0}, factor_t::ROLE_LOOP_CLOSURE)};
  g.num_alternatives = 2;
  g.null_hypothesis = true;
  b.ambiguous = {g};
  b.num_ambiguous = 1;
  f.send(b);
  ASSERT_TRUE(f.out.errors.empty()) << f.out.errors.front().reason;
  const std::string path = testing_live::tmp("snap_amb.g2o");
  f.command(C::SAVE_SNAPSHOT, path, {}, 6);
  ASSERT_TRUE(f.out.errors.empty()) << f.out.errors.back().reason;
  io::Dataset ds;
  ASSERT_NO_THROW(ds = io::readDataset(path)) << fileText(path);
  EXPECT_EQ(ds.edges.size(), 8u);
  ASSERT_EQ(ds.hypotheses.size(), 1u);
  EXPECT_EQ(ds.hypotheses[0].firstEdge, 6);
  EXPECT_EQ(ds.hypotheses[0].count, 2);
  EXPECT_TRUE(ds.hypotheses[0].null);
  EXPECT_EQ(ds.edges[7].to, 1);
}

TEST(EngineCommands, SnapshotOf3dRobotsReadsBackAsTheSameGraph) {
  Fixture f;
  Eigen::Matrix<double, 6, 6> info = Eigen::Matrix<double, 6, 6>::Identity() * 100;
  info(0, 4) = info(4, 0) = 5;
  auto between3 = [&](std::int64_t id, int ra, std::int64_t a, int rb, std::int64_t b,
                      Eigen::Vector3d t, double yaw, int8_t role) {
    client::Pose3 z;
    z.t = t;
    z.q = Eigen::Quaterniond(Eigen::AngleAxisd(yaw, Eigen::Vector3d(0.1, 0.2, 1).normalized()));
    factor_t w = client::loopClosureFactor(KeyRef::pose(ra, a), KeyRef::pose(rb, b), z, info);
    w.id = id;
    w.role = role;
    return w;
  };
  std::vector<factor_t> a, b;
  for (int i = 0; i < 4; ++i)
    a.push_back(between3(i, 0, i, 0, i + 1, {1, 0, 0.1}, 0.2, factor_t::ROLE_ODOMETRY));
  for (int i = 0; i < 4; ++i)
    b.push_back(between3(i, 1, i, 1, i + 1, {0.5, 0.5, 0}, -0.1, factor_t::ROLE_ODOMETRY));
  Eigen::Matrix3d pinfo;
  pinfo << 30, 2, 1, 2, 20, 0, 1, 0, 10;
  a.push_back(client::landmarkFactor(KeyRef::pose(0, 2), KeyRef::point(0, 0),
                                     Eigen::Vector3d(1, 2, 3), pinfo));
  a.back().id = 50;
  f.send(batch("a", ++f.seq0, a));
  f.send(batch("b", ++f.seq1, b));
  f.send(batch("b", ++f.seq1,
               {between3(100, 0, 4, 1, 0, {0, 3, 0}, 0.5, factor_t::ROLE_LOOP_CLOSURE),
                between3(101, 0, 0, 1, 4, {1, 4, 0.3}, 0.1, factor_t::ROLE_LOOP_CLOSURE)}));
  ASSERT_TRUE(f.out.errors.empty()) << f.out.errors.front().reason;
  f.command(C::OPTIMIZE, "", {}, 1);
  const std::string path = testing_live::tmp("snap3d.g2o");
  f.command(C::SAVE_SNAPSHOT, path, {}, 6);
  ASSERT_TRUE(f.out.errors.empty()) << f.out.errors.back().reason;
  io::Dataset ds;
  ASSERT_NO_THROW(ds = io::readDataset(path)) << fileText(path);
  EXPECT_TRUE(ds.is3d);
  EXPECT_EQ(ds.poses.size(), 10u);
  EXPECT_EQ(ds.landmarks.size(), 1u);
  EXPECT_EQ(ds.edges.size(), 11u);
  const auto& sighting = ds.edges[4];
  ASSERT_EQ(sighting.type, io::EdgeType::PosePoint3);
  EXPECT_TRUE((sighting.information.topLeftCorner<3, 3>().isApprox(pinfo, 1e-12)));
  const PoseGraphProblem p = buildProblem(ds);
  const double serverChi2 = f.engine.backend().chi2();
  EXPECT_GT(serverChi2, 0.1);
  EXPECT_NEAR(p.graph.chi2(p.initial), serverChi2, 1e-6 * serverChi2);
}

// --- bug C: flags -------------------------------------------------------------------------

TEST(EngineCommands, ServerFlagsRefuseUnknownLogLevelsAndNumbersOutOfRange) {
  for (const auto& l : logLevelNames())
    EXPECT_EQ(parseServerConfig({"--log-level", l}).logLevel, l);
  for (const std::string l : {"loud", "INFO", "warning", "", "err"})
    EXPECT_THROW(parseServerConfig({"--log-level", l}), std::invalid_argument) << l;
  try {
    parseServerConfig({"--log-level", "loud"});
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("trace|debug|info|warn|error|critical|off"),
              std::string::npos)
        << e.what();
  }
  for (const std::string flag : {"--idle-seconds", "--hold-seconds"}) {
    for (const std::string v :
         {"nan", "NaN", "inf", "-inf", "infinity", "-1", "1e300", "86401", "", " 1", "1s", "0.5.1"})
      EXPECT_THROW(parseServerConfig({flag, v}), std::invalid_argument) << flag << " " << v;
    EXPECT_NO_THROW(parseServerConfig({flag, "0"}));
    EXPECT_NO_THROW(parseServerConfig({flag, "86400"}));
  }
  EXPECT_DOUBLE_EQ(parseServerConfig({"--idle-seconds", "0.25"}).idleSeconds, 0.25);
  for (const std::string flag : {"--publish-every", "--hold-max", "--max-hypotheses"}) {
    for (const std::string v :
         {"nan", "-1", "1e3", "2.5", " 3", "+3", "3 ", "1000001", "99999999999999999999"})
      EXPECT_THROW(parseServerConfig({flag, v}), std::invalid_argument) << flag << " " << v;
  }
  EXPECT_THROW(parseServerConfig({"--max-hypotheses", "1001"}), std::invalid_argument);
  for (const std::string v : {"0", "1001", "-1", "nan", "2.5"})
    EXPECT_THROW(parseServerConfig({"--idle-rounds", v}), std::invalid_argument) << v;
  EXPECT_EQ(parseServerConfig({}).idleRounds, 10);
  EXPECT_EQ(parseServerConfig({"--idle-rounds", "1"}).idleRounds, 1);
  EXPECT_EQ(parseServerConfig({"--idle-rounds", "1000"}).idleRounds, 1000);
  EXPECT_EQ(parseServerConfig({"--max-hypotheses", "1000"}).maxHypotheses, 1000);
  EXPECT_EQ(parseServerConfig({"--hold-max", "1000000"}).holdMax, 1000000);
  EXPECT_EQ(parseServerConfig({"--publish-every", "0"}).publishEvery, 0);
  // The config file goes through the same checks.
  const std::string path = testing_live::tmp("loopd_bad.conf");
  std::ofstream(path) << "idle-seconds = nan\n";
  EXPECT_THROW(parseServerConfig({"--config", path}), std::invalid_argument);
  std::ofstream(path) << "log-level = loud\n";
  EXPECT_THROW(parseServerConfig({"--config", path}), std::invalid_argument);
}

TEST(EngineCommands, LoopdExitsWithAUsageErrorForABadLogLevelOrNumber) {
  using testing_live::Proc;
  {
    Proc p = Proc::start({testing_live::kLoopd, "--lcm-url", "memq://", "--log-level", "loud"},
                         testing_live::tmp("loud.log"));
    EXPECT_EQ(p.wait(30), 2);
    EXPECT_NE(p.output().find("--log-level: 'loud' is not one of "
                              "trace|debug|info|warn|error|critical|off"),
              std::string::npos)
        << p.output();
    EXPECT_NE(p.output().find("usage: loopd"), std::string::npos);
  }
  for (const std::string flag : {"--idle-seconds", "--hold-seconds"}) {
    Proc p = Proc::start({testing_live::kLoopd, "--lcm-url", "memq://", flag, "nan"},
                         testing_live::tmp("nan.log"));
    EXPECT_EQ(p.wait(30), 2) << flag;
    EXPECT_NE(p.output().find(flag + ": 'nan' is not a number"), std::string::npos) << p.output();
  }
}

}  // namespace
