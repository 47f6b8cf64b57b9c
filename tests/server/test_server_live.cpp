// loopd end to end over real LCM (a udpm port per test): loopd-feed → loopd → loopd-listen,
// compared with the offline loopd-solve of the same data; lcm-logplayer replay; kill -9 and
// --resume; duplicates; a fuzz barrage on the factor channel.
#include <lcm/lcm-cpp.hpp>

#include <random>

#include "client/estimate_subscriber.h"
#include "client/factor_publisher.h"
#include "loopd/command_t.hpp"
#include "tests/server/live_util.h"

using namespace loopd;
using namespace loopd::testing_live;

namespace {

double listenedField(const std::string& out, const std::string& field) {
  const auto p = out.find(field);
  return p == std::string::npos ? -1.0 : std::stod(out.substr(p + field.size()));
}

struct Offline {
  double chi2;
  std::map<long, std::vector<double>> poses;
};

// loopd-solve (batch LM) of a dataset, cached per file.
const Offline& offline(const std::string& dataset) {
  static std::map<std::string, Offline> cache;
  auto it = cache.find(dataset);
  if (it != cache.end()) return it->second;
  const std::string est = tmp("offline_est.g2o"), stats = tmp("offline_stats.json");
  EXPECT_EQ(runTool({kSolve, dataset, "--out", est, "--stats", stats, "--quiet"}, tmp("solve.log")),
            0);
  return cache[dataset] = Offline{statsChi2(stats), readVertices(est)};
}

// Starts loopd with extra flags on url.
Proc server(const std::string& url, const std::vector<std::string>& extra, const std::string& log) {
  std::vector<std::string> args = {kLoopd, "--lcm-url", url, "--log-level", "info"};
  args.insert(args.end(), extra.begin(), extra.end());
  Proc p = Proc::start(args, log);
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  return p;
}

void expectMatchesOffline(const std::string& dataset, const std::string& listenOut,
                          const std::string& est, size_t poses) {
  const Offline& off = offline(dataset);
  const double chi2 = listenedChi2(listenOut);
  EXPECT_NEAR(chi2, off.chi2, 1e-6 * off.chi2) << listenOut;
  const auto got = readVertices(est);
  EXPECT_EQ(got.size(), poses);
  const auto [dt, dr] = maxDifference(got, off.poses);
  EXPECT_LT(dt, 2e-3) << "max position difference";
  EXPECT_LT(dr, 2e-4) << "max heading difference";
  std::printf("    chi2 %.9f (offline %.9f), max |dt| %.2e m, |dtheta| %.2e rad\n", chi2, off.chi2,
              dt, dr);
}

TEST(ServerLive, IntelMatchesOfflineSolve) {
  const std::string url = uniqueUrl();
  const std::string data = kData + "/intel.g2o";
  Proc srv = server(url, {}, tmp("srv.log"));
  ASSERT_TRUE(srv.alive()) << srv.output();
  const std::string est = tmp("est.g2o");
  Proc listen = Proc::start({kListen, "--lcm-url", url, "--out", est, "--until-batches", "1728"},
                            tmp("listen.log"));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  ASSERT_EQ(runTool({kFeed, data, "--lcm-url", url}, tmp("feed.log")), 0);
  ASSERT_EQ(listen.wait(60), 0) << listen.output();
  srv.kill(SIGINT);
  EXPECT_EQ(srv.wait(20), 0) << srv.output();
  expectMatchesOffline(data, listen.output(), est, 1728);
  EXPECT_NE(listen.output().find("1728 batches accepted"), std::string::npos) << listen.output();
}

TEST(ServerLive, FourRobotCity10000EndsInOneFrameAtTheOptimum) {
  const std::string url = uniqueUrl();
  const std::string data = kData + "/city10000.g2o";
  Proc srv = server(url, {}, tmp("srv.log"));
  const std::string est = tmp("est.g2o");
  // Ends on the server's own word (every batch handled, the estimate converged), not on a
  // quiet spell: under load one update can outlast any fixed quiet time.
  Proc listen = Proc::start({kListen, "--lcm-url", url, "--out", est, "--until-batches", "10000"},
                            tmp("listen.log"));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  // Paced: unpaced, the 10000 batches leave in 0.08 s. In the twenty-second session's CI (a
  // headless browser starting in the other `ctest -j 2` slot) the server's log stopped after
  // the robots joined and it never reported 10000 handled: most likely a burst udpm dropped.
  ASSERT_EQ(
      runTool({kFeed, data, "--robots", "4", "--rate", "4000", "--lcm-url", url}, tmp("feed.log")),
      0);
  ASSERT_EQ(listen.wait(180 * kSlowdown), 0) << listen.output();
  srv.kill(SIGTERM);
  EXPECT_EQ(srv.wait(30), 0) << srv.output();
  EXPECT_NE(listen.output().find("4 robots, 4 in a common frame"), std::string::npos)
      << listen.output();
  expectMatchesOffline(data, listen.output(), est, 10000);
}

TEST(ServerLive, LogplayerReplayGivesTheSameResult) {
  const std::string url = uniqueUrl();
  const std::string data = kData + "/intel.g2o";
  const std::string log = tmp("intel.lcmlog");
  ASSERT_EQ(runTool({kFeed, data, "--robots", "2", "--log", log}, tmp("feed.log")), 0);
  Proc srv = server(url, {}, tmp("srv.log"));
  const std::string est = tmp("est.g2o");
  Proc listen = Proc::start({kListen, "--lcm-url", url, "--out", est, "--until-quiet", quietFor(2)},
                            tmp("listen.log"));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  // 1 ms between logged batches: real time at 4x.
  ASSERT_EQ(runTool({"/usr/bin/lcm-logplayer", "-s", "4", "-l", url, log}, tmp("player.log")), 0);
  ASSERT_EQ(listen.wait(60), 0) << listen.output();
  srv.kill(SIGINT);
  EXPECT_EQ(srv.wait(20), 0);
  EXPECT_NE(listen.output().find("2 robots, 2 in a common frame"), std::string::npos)
      << listen.output();
  expectMatchesOffline(data, listen.output(), est, 1728);
}

TEST(ServerLive, KillNineResumeFeedTheRestLosesNothing) {
  const std::string url = uniqueUrl();
  const std::string data = kData + "/intel.g2o";
  const std::string journal = tmp("journal.lcmlog");
  std::remove(journal.c_str());
  {
    Proc srv = server(url, {"--journal", journal}, tmp("srv1.log"));
    Proc feed =
        Proc::start({kFeed, data, "--lcm-url", url, "--rate", "1500", "--quiet"}, tmp("feed1.log"));
    std::this_thread::sleep_for(std::chrono::milliseconds(600));
    srv.kill(SIGKILL);  // in the middle
    ASSERT_EQ(feed.wait(30), 0);
  }
  Proc srv = server(url, {"--journal", journal, "--resume", journal}, tmp("srv2.log"));
  EXPECT_TRUE(srv.waitForOutput("resumed", 60)) << srv.output();  // 1.1 s under ASan
  const std::string est = tmp("est.g2o");
  Proc listen = Proc::start({kListen, "--lcm-url", url, "--out", est, "--until-quiet", quietFor(2)},
                            tmp("listen.log"));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  ASSERT_EQ(runTool({kFeed, data, "--lcm-url", url, "--quiet"}, tmp("feed2.log")),
            0);  // everything again
  ASSERT_EQ(listen.wait(60), 0) << listen.output();
  srv.kill(SIGTERM);
  EXPECT_EQ(srv.wait(20), 0);
  const std::string lo = listen.output();
  EXPECT_NE(lo.find("1728 batches accepted"), std::string::npos) << lo << srv.output();
  const double dup = listenedField(lo, "accepted, ");
  EXPECT_GT(dup, 0) << "the resumed batches come again as duplicates: " << lo;
  expectMatchesOffline(data, lo, est, 1728);
  // The journal now holds every batch once: a third server resuming it alone has the same graph.
  Proc third = server(url, {"--resume", journal, "--idle-seconds", "0.1"}, tmp("srv3.log"));
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  third.kill(SIGINT);
  EXPECT_EQ(third.wait(20), 0);
  EXPECT_NE(third.output().find("1728 batches accepted"), std::string::npos) << third.output();
}

TEST(ServerLive, DuplicateFeedIsAppliedOnce) {
  const std::string url = uniqueUrl();
  const std::string data = kData + "/intel.g2o";
  Proc srv = server(url, {"--solver", "lm"}, tmp("srv.log"));
  const std::string est = tmp("est.g2o");
  Proc listen = Proc::start({kListen, "--lcm-url", url, "--out", est, "--until-quiet", quietFor(2)},
                            tmp("listen.log"));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  ASSERT_EQ(runTool({kFeed, data, "--lcm-url", url, "--poses", "500", "--quiet"}, tmp("feed1.log")),
            0);
  ASSERT_EQ(runTool({kFeed, data, "--lcm-url", url, "--poses", "500", "--quiet"}, tmp("feed2.log")),
            0);
  ASSERT_EQ(listen.wait(60), 0) << listen.output();
  srv.kill(SIGINT);
  EXPECT_EQ(srv.wait(20), 0);
  EXPECT_NE(listen.output().find("500 batches accepted, 500 duplicate, 0 rejected"),
            std::string::npos)
      << listen.output();
}

// loopd-listen's summary counts the batches the server dropped after holding them too long
// (before, it named accepted, duplicate and rejected only: a run that lost half its batches
// to expiry read as clean).
TEST(ServerLive, ListenSaysHowManyBatchesExpired) {
  const std::string url = uniqueUrl();
  Proc srv = server(url, {"--hold-seconds", "1"}, tmp("srv.log"));
  Proc listen =
      Proc::start({kListen, "--lcm-url", url, "--out", tmp("est.g2o"), "--until-batches", "2"},
                  tmp("listen.log"));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  lcm::LCM lcm(url);
  ASSERT_TRUE(lcm.good());
  client::FactorPublisher fe(lcm, "fe");
  const Eigen::Matrix3d info = Eigen::Vector3d(100, 100, 1000).asDiagonal();
  fe.odometry(0, 0, 1, {1, 0, 0}, info);
  fe.flush();
  fe.odometry(0, 5, 6, {1, 0, 0}, info);  // pose 5 never comes: held, then expired
  fe.flush();
  ASSERT_EQ(listen.wait(30 * kSlowdown), 0) << listen.output();
  srv.kill(SIGINT);
  EXPECT_EQ(srv.wait(20), 0);
  EXPECT_NE(listen.output().find("1 batches accepted, 0 duplicate, 0 rejected, 1 expired, 0 held"),
            std::string::npos)
      << listen.output();
}

// --- fuzz -----------------------------------------------------------------------------------

factor_t odo(std::int64_t id, int robot, std::int64_t a, double x = 1.0) {
  factor_t f{};
  f.id = id;
  f.type = factor_t::BETWEEN_SE2;
  f.role = factor_t::ROLE_ODOMETRY;
  f.keys = {client::wireKey(client::KeyRef::pose(robot, a)),
            client::wireKey(client::KeyRef::pose(robot, a + 1))};
  f.num_keys = 2;
  f.measurement = {x, 0.1, 0.05};
  f.num_measurement = 3;
  f.noise_kind = factor_t::NOISE_INFORMATION;
  f.noise = {100, 0, 0, 100, 0, 1000};
  f.num_noise = 6;
  f.robust = "";
  return f;
}

std::vector<uint8_t> encodeBatch(const std::string& sender, std::int64_t seq,
                                 std::vector<factor_t> fs,
                                 std::vector<std::int64_t> removals = {}) {
  factor_batch_t b{};
  b.sender = sender;
  b.sequence = seq;
  b.factors = std::move(fs);
  b.num_factors = static_cast<int16_t>(b.factors.size());
  b.remove_ids = std::move(removals);
  b.num_remove_ids = static_cast<int16_t>(b.remove_ids.size());
  std::vector<uint8_t> buf(static_cast<size_t>(b.getEncodedSize()));
  b.encode(buf.data(), 0, static_cast<int>(buf.size()));
  return buf;
}

TEST(ServerLive, FuzzedFactorChannelLeavesServerAliveAndGraphIntact) {
  const std::string url = uniqueUrl();
  Proc srv = server(url, {"--idle-seconds", "0.2"}, tmp("srv.log"));
  lcm::LCM lcm(client::receiveUrl(url));
  ASSERT_TRUE(lcm.good());
  client::EstimateSubscriber sub(lcm);
  auto pump = [&](double seconds) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < end) lcm.handleTimeout(20);
  };
  auto publish = [&](const std::vector<uint8_t>& b) {
    lcm.publish("LOOPD_FACTORS", b.data(), static_cast<unsigned>(b.size()));
    lcm.handleTimeout(1);
  };
  // The real graph: robot 0, 30 poses.
  for (int i = 0; i < 30; ++i) publish(encodeBatch("good", i + 1, {odo(i, 0, i)}));
  pump(1.0);
  const auto clean = sub.robot(0);
  ASSERT_EQ(clean.poses.size(), 31u);
  const double cleanChi2 = sub.lastStatus().chi2;

  std::mt19937 rng(42);
  std::uniform_int_distribution<int> byte(0, 255);
  int expectedErrors = 0;
  const auto before = sub.errorsReceived();
  // Random bytes (some with the right fingerprint), truncations.
  const auto valid = encodeBatch("fuzz", 1, {odo(0, 7, 0), odo(1, 7, 1)});
  for (int i = 0; i < 60; ++i) {
    std::vector<uint8_t> junk(static_cast<size_t>(1 + rng() % 400));
    for (auto& c : junk) c = static_cast<uint8_t>(byte(rng));
    if (i % 2 == 0 && junk.size() > 8) std::copy(valid.begin(), valid.begin() + 8, junk.begin());
    publish(junk);
    ++expectedErrors;
    std::vector<uint8_t> cut(valid.begin(),
                             valid.begin() + static_cast<long>(rng() % (valid.size() - 1)));
    publish(cut);
    ++expectedErrors;
  }
  // Bit flips of a valid batch about robot 7 (disconnected from robot 0, other sender).
  for (int i = 0; i < 200; ++i) {
    auto b = encodeBatch("fuzz", 100 + i, {odo(1000 + i, 7, i)});
    b[rng() % b.size()] ^= static_cast<uint8_t>(1u << (rng() % 8));
    publish(b);
  }
  // Semantic garbage from the real sender's robot (all refused).
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::int64_t seq = 1000;
  auto bad = [&](std::function<void(factor_t&)> mutate) {
    factor_t f = odo(5000 + seq, 0, 30);
    mutate(f);
    publish(encodeBatch("good", ++seq, {f}));
    ++expectedErrors;
  };
  bad([&](factor_t& f) { f.measurement[0] = nan; });
  bad([&](factor_t& f) { f.noise[3] = std::numeric_limits<double>::infinity(); });
  bad([&](factor_t& f) { f.noise = {1, 0, 0, -1, 0, 1}; });
  bad([&](factor_t& f) {
    f.noise.resize(3);
    f.num_noise = 3;
  });
  bad([&](factor_t& f) {
    f.measurement.resize(7, 0.0);
    f.num_measurement = 7;
  });
  bad([&](factor_t& f) { f.keys[1].kind = loopd::key_t::LANDMARK; });
  bad([&](factor_t& f) { f.type = 77; });
  bad([&](factor_t& f) { f.id = 3; });                // an id "good" already used
  publish(encodeBatch("good", ++seq, {}, {424242}));  // unknown removal id
  ++expectedErrors;
  pump(1.5);
  EXPECT_TRUE(srv.alive()) << srv.output();
  EXPECT_GE(sub.errorsReceived() - before, expectedErrors);
  // Robot 0 is exactly as before.
  loopd::command_t req{};
  req.sender = "test";
  req.request_id = 9;
  req.command = loopd::command_t::REQUEST_ESTIMATE;
  req.argument = "0";
  lcm.publish("LOOPD_COMMAND", &req);
  pump(0.8);
  const auto after = sub.robot(0);
  ASSERT_EQ(after.poses.size(), 31u);
  for (const auto& [i, x] : clean.poses)
    for (size_t k = 0; k < 3; ++k) EXPECT_NEAR(after.poses.at(i)[k], x[k], 1e-6) << "pose " << i;
  const auto st = sub.lastStatus();
  EXPECT_GE(st.batches_rejected, expectedErrors - 120 /* decode failures also count */);
  // Every refusal names its sender/sequence when it had one.
  for (const auto& e : sub.errors())
    if (e.sender == "good") EXPECT_GT(e.sequence, 1000);
  (void)cleanChi2;
  srv.kill(SIGTERM);
  EXPECT_EQ(srv.wait(20), 0) << srv.output();
}

}  // namespace
