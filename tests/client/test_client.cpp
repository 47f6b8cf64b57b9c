// loopd_client: batching, sequence numbers, resend (captured sink), and the subscriber's
// assembly of chunked estimates over memq://.
#include <gtest/gtest.h>
#include <lcm/lcm-cpp.hpp>

#include "client/estimate_subscriber.h"
#include "client/factor_publisher.h"

using namespace loopd;
using client::KeyRef;
using client::Pose2;

namespace {

struct Capture {
  std::vector<factor_batch_t> batches;
  std::vector<std::vector<uint8_t>> raw;
  client::BatchSink sink() {
    return [this](const std::string& ch, const std::vector<uint8_t>& b) {
      EXPECT_EQ(ch, "X_FACTORS");
      factor_batch_t m;
      EXPECT_EQ(m.decode(b.data(), 0, static_cast<int>(b.size())), static_cast<int>(b.size()));
      batches.push_back(m);
      raw.push_back(b);
    };
  }
};

TEST(FactorPublisher, SequencesIdsAndNoiseLayout) {
  Capture cap;
  client::FactorPublisher pub(cap.sink(), "robot1/vio", "X_FACTORS");
  EXPECT_EQ(pub.flush(), 0);  // nothing pending
  Eigen::Matrix3d info;
  info << 1, 2, 3, 2, 4, 5, 3, 5, 6;
  EXPECT_EQ(pub.odometry(1, 0, 1, Pose2{1, 0, 0}, info), 0);
  EXPECT_EQ(
      pub.loopClosure(KeyRef::pose(1, 1), KeyRef::pose(2, 7), Pose2{0, 1, 0}, info, "dcs", 2.0), 1);
  pub.initialValue(KeyRef::pose(1, 0), Pose2{0, 0, 0});
  EXPECT_EQ(pub.flush(), 1);
  pub.remove(1);
  EXPECT_EQ(pub.odometry(1, 1, 2, Pose2{1, 0, 0}, info, 50), 50);
  EXPECT_EQ(pub.odometry(1, 2, 3, Pose2{1, 0, 0}, info), 51);
  EXPECT_EQ(pub.flush(), 2);
  ASSERT_EQ(cap.batches.size(), 2u);
  const auto& b = cap.batches[0];
  EXPECT_EQ(b.sender, "robot1/vio");
  EXPECT_EQ(b.sequence, 1);
  ASSERT_EQ(b.num_factors, 2);
  EXPECT_EQ(b.factors[0].role, factor_t::ROLE_ODOMETRY);
  EXPECT_EQ(b.factors[1].role, factor_t::ROLE_LOOP_CLOSURE);
  EXPECT_EQ(b.factors[1].robust, "dcs");
  EXPECT_EQ(b.factors[1].keys[1].robot, 2);
  EXPECT_EQ(b.factors[0].noise, (std::vector<double>{1, 2, 3, 4, 5, 6}));  // g2o upper triangle
  EXPECT_EQ(b.num_initial_values, 1);
  EXPECT_EQ(cap.batches[1].sequence, 2);
  EXPECT_EQ(cap.batches[1].remove_ids, std::vector<int64_t>{1});
  EXPECT_TRUE(pub.resendLast());
  ASSERT_EQ(cap.raw.size(), 3u);
  EXPECT_EQ(cap.raw[2], cap.raw[1]);  // same bytes, same sequence
}

// Removing what the pending batch adds takes it out of the batch (before: the batch carried
// both, and the server refused all of it, the odometry with it: UNKNOWN_FACTOR_ID).
TEST(FactorPublisher, RemovingAFactorOfThePendingBatchTakesItOut) {
  Capture cap;
  client::FactorPublisher pub(cap.sink(), "a", "X_FACTORS");
  const Eigen::Matrix3d info = Eigen::Matrix3d::Identity();
  pub.odometry(0, 0, 1, Pose2{1, 0, 0}, info);
  const std::int64_t closure =
      pub.loopClosure(KeyRef::pose(0, 1), KeyRef::pose(0, 0), Pose2{-1, 0, 0}, info);
  EXPECT_EQ(pub.pendingItems(), 2);
  pub.remove(closure);
  EXPECT_EQ(pub.pendingItems(), 1);
  pub.remove(closure + 100);  // not pending: a removal for the server
  EXPECT_EQ(pub.flush(), 1);
  ASSERT_EQ(cap.batches.size(), 1u);
  ASSERT_EQ(cap.batches[0].num_factors, 1);
  EXPECT_EQ(cap.batches[0].factors[0].role, factor_t::ROLE_ODOMETRY);
  EXPECT_EQ(cap.batches[0].remove_ids, std::vector<int64_t>{closure + 100});
}

TEST(FactorPublisher, FlushesAtMaxItems) {
  Capture cap;
  client::FactorPublisher pub(cap.sink(), "a", "X_FACTORS");
  for (int i = 0; i < 450; ++i)
    pub.odometry(0, i, i + 1, Pose2{1, 0, 0}, Eigen::Matrix3d::Identity());
  pub.flush();
  ASSERT_EQ(cap.batches.size(), 3u);
  EXPECT_EQ(cap.batches[0].num_factors, factor_batch_t::MAX_ITEMS);
  EXPECT_EQ(cap.batches[2].num_factors, 50);
  EXPECT_EQ(cap.batches[2].sequence, 3);
  EXPECT_THROW(client::FactorPublisher(cap.sink(), ""), std::invalid_argument);
}

TEST(FactorPublisher, AmbiguousGroupsAndTheServersRules) {
  using A = ambiguous_factor_t;
  Capture cap;
  client::FactorPublisher pub(cap.sink(), "a", "X_FACTORS");
  const Eigen::Matrix3d info = Eigen::Vector3d(100, 100, 1000).asDiagonal();
  const Eigen::Matrix2d info2 = Eigen::Vector2d(10, 20).asDiagonal();
  pub.odometry(0, 0, 1, Pose2{1, 0, 0}, info);  // id 0
  const auto place = pub.ambiguous(
      A::MULTI_ASSOCIATION,
      {client::loopClosureFactor(KeyRef::pose(0, 9), KeyRef::pose(0, 0), Pose2{}, info),
       client::loopClosureFactor(KeyRef::pose(0, 9), KeyRef::pose(0, 4), Pose2{}, info)},
      true, 0.5);
  const auto tree = pub.ambiguous(A::MULTI_ASSOCIATION,
                                  {client::landmarkFactor(KeyRef::pose(0, 9), KeyRef::point(0, 1),
                                                          Eigen::Vector2d(1, 2), info2),
                                   client::landmarkFactor(KeyRef::pose(0, 9), KeyRef::point(0, 2),
                                                          Eigen::Vector2d(1, 2), info2),
                                   client::landmarkFactor(KeyRef::pose(0, 9), KeyRef::point(0, 3),
                                                          Eigen::Vector2d(1, 2), info2)},
                                  false, 0.0, 77);
  EXPECT_EQ(place, 1);  // the factor id space
  EXPECT_EQ(tree, 77);
  EXPECT_EQ(pub.pendingItems(), 1 + 2 + 3);  // alternatives count as items
  pub.flush();
  ASSERT_EQ(cap.batches.size(), 1u);
  const auto& b = cap.batches[0];
  ASSERT_EQ(b.num_ambiguous, 2);
  EXPECT_EQ(b.ambiguous[0].id, 1);
  EXPECT_EQ(b.ambiguous[0].mode, A::MULTI_ASSOCIATION);
  ASSERT_EQ(b.ambiguous[0].num_alternatives, 2);
  EXPECT_TRUE(b.ambiguous[0].null_hypothesis);
  EXPECT_DOUBLE_EQ(b.ambiguous[0].null_weight, 0.5);
  EXPECT_EQ(b.ambiguous[0].alternatives[1].role, factor_t::ROLE_LOOP_CLOSURE);
  EXPECT_EQ(b.ambiguous[0].alternatives[1].keys[1].index, 4);
  EXPECT_EQ(b.ambiguous[0].alternatives[1].noise, (std::vector<double>{100, 0, 0, 100, 0, 1000}));
  EXPECT_EQ(b.ambiguous[1].alternatives[2].type, factor_t::POSE_POINT2);
  EXPECT_EQ(b.ambiguous[1].alternatives[2].role, factor_t::ROLE_LANDMARK);
  EXPECT_EQ(b.ambiguous[1].alternatives[2].keys[1].kind, loopd::key_t::LANDMARK);
  EXPECT_EQ(b.ambiguous[1].alternatives[2].id, 0);

  auto lc = [&](int64_t to, double x) {
    return client::loopClosureFactor(KeyRef::pose(0, 9), KeyRef::pose(0, to), Pose2{x, 0, 0}, info);
  };
  // What the server would refuse is refused here, and nothing is queued.
  EXPECT_THROW(pub.ambiguous(0, {lc(0, 0), lc(4, 0)}, false), std::invalid_argument);  // mode
  EXPECT_THROW(pub.ambiguous(A::MULTI_ASSOCIATION, {lc(0, 0)}, false),
               std::invalid_argument);                                                 // k = 1
  EXPECT_THROW(pub.ambiguous(A::MULTI_ASSOCIATION, {}, true), std::invalid_argument);  // k = 0
  EXPECT_THROW(pub.ambiguous(A::MULTI_ASSOCIATION, {lc(0, 0), lc(4, 0)}, true, -1),
               std::invalid_argument);  // weight
  EXPECT_THROW(pub.ambiguous(A::MULTI_ASSOCIATION, {lc(0, 0), lc(4, 1)}, false),
               std::invalid_argument);  // measurement
  EXPECT_THROW(pub.ambiguous(A::MULTI_ASSOCIATION, {lc(0, 0), lc(0, 0)}, false),
               std::invalid_argument);  // same keys
  EXPECT_THROW(pub.ambiguous(A::MULTI_MEASUREMENT, {lc(0, 0), lc(4, 1)}, false),
               std::invalid_argument);  // keys differ
  std::vector<factor_t> many;
  for (int i = 0; i < 17; ++i) many.push_back(lc(i, 0));
  EXPECT_THROW(pub.ambiguous(A::MULTI_ASSOCIATION, many, false), std::invalid_argument);
  factor_t odo = lc(0, 0);
  odo.role = factor_t::ROLE_ODOMETRY;
  EXPECT_THROW(pub.ambiguous(A::MULTI_MEASUREMENT, {odo, odo}, false), std::invalid_argument);
  EXPECT_EQ(pub.pendingItems(), 0);
  EXPECT_NO_THROW(pub.ambiguous(A::MULTI_MEASUREMENT, {lc(0, 0), lc(0, 1)}, false));
  EXPECT_EQ(pub.pendingItems(), 2);
  // Inter-robot alternatives: whether the robots are joined yet is the server's to judge.
  factor_t inter = lc(0, 0), inter2 = lc(0, 1);
  inter.keys[1].robot = inter2.keys[1].robot = 3;
  EXPECT_NO_THROW(pub.ambiguous(A::MULTI_MEASUREMENT, {inter, inter2}, true));
  EXPECT_EQ(pub.pendingItems(), 4);
}

estimate_t chunk(int64_t seq, int robot, bool full, int index, int count,
                 std::vector<int64_t> ids) {
  estimate_t e{};
  e.update_seq = seq;
  e.robot = robot;
  e.frame_robot = 0;
  e.common_frame = robot != 0;
  e.full_snapshot = full;
  e.chunk_index = index;
  e.chunk_count = count;
  e.pose_type = estimate_t::SE2;
  e.pose_dim = 3;
  e.landmark_dim = 2;
  for (int64_t i : ids) {
    e.pose_indices.push_back(i);
    e.poses.push_back({double(i), double(seq), 0});
  }
  e.num_poses = static_cast<int16_t>(ids.size());
  return e;
}

TEST(EstimateSubscriber, AssemblesSnapshotsAndDeltas) {
  lcm::LCM lcm("memq://");
  ASSERT_TRUE(lcm.good());
  client::EstimateSubscriber sub(lcm, "X_");
  int calls = 0;
  sub.onEstimate([&](const client::RobotEstimate&, const estimate_t&) { ++calls; });
  auto send = [&](const estimate_t& e) {
    lcm.publish("X_ESTIMATE", &e);
    lcm.handleTimeout(10);
  };
  send(chunk(1, 0, false, 0, 1, {0, 1, 2}));
  EXPECT_EQ(sub.robot(0).poses.size(), 3u);
  send(chunk(2, 0, true, 0, 2, {0, 1}));  // first half of a snapshot: not applied yet
  EXPECT_EQ(sub.robot(0).poses.at(0)[1], 1.0);
  send(chunk(2, 0, true, 1, 2, {5}));  // complete: replaces the table (2 is gone)
  const auto r = sub.robot(0);
  EXPECT_EQ(r.poses.size(), 3u);
  EXPECT_EQ(r.poses.count(2), 0u);
  EXPECT_EQ(r.poses.at(5)[1], 2.0);
  send(chunk(3, 1, false, 0, 1, {9}));
  EXPECT_TRUE(sub.robot(1).commonFrame);
  EXPECT_EQ(sub.robots(), (std::vector<int32_t>{0, 1}));
  EXPECT_EQ(calls, 3);

  covariance_t c{};
  c.keys = {client::wireKey(KeyRef::pose(1, 9))};
  c.num_keys = 1;
  c.dims = {3};
  c.values = {1, 0, 0, 0, 2, 0, 0, 0, 3};
  c.num_values = 9;
  c.chunk_count = 1;
  lcm.publish("X_COVARIANCE", &c);
  lcm.handleTimeout(10);
  EXPECT_EQ(sub.latestCovariances().at(1).first, 9);
  EXPECT_EQ(sub.latestCovariances().at(1).second[4], 2.0);
  EXPECT_EQ(client::receiveUrl("udpm://239.255.76.67:7667?ttl=0"),
            "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304");
}

status_t statusOf(int64_t seq, int32_t robots, int64_t poses, int64_t landmarks = 0) {
  status_t s{};
  s.update_seq = seq;
  s.solver = "isam2";
  s.robots = robots;
  s.poses = poses;
  s.landmarks = landmarks;
  s.decisions_chunk_count = 1;
  return s;
}

/// A subscriber on memq:// and the X_ prefix, with helpers that publish and deliver at once.
struct Follower {
  lcm::LCM lcm{"memq://"};
  client::EstimateSubscriber sub{lcm, "X_"};
  std::vector<int64_t> forgotAt;
  Follower() {
    sub.onForget([this](int64_t seq) { forgotAt.push_back(seq); });
  }
  void estimate(const estimate_t& e) {
    lcm.publish("X_ESTIMATE", &e);
    lcm.handleTimeout(10);
  }
  void status(const status_t& s) {
    lcm.publish("X_STATUS", &s);
    lcm.handleTimeout(10);
  }
  void covariance(int robot, int64_t index, int64_t seq) {
    covariance_t c{};
    c.update_seq = seq;
    c.keys = {client::wireKey(KeyRef::pose(robot, index))};
    c.num_keys = 1;
    c.dims = {3};
    c.values = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    c.num_values = 9;
    c.chunk_count = 1;
    lcm.publish("X_COVARIANCE", &c);
    lcm.handleTimeout(10);
  }
};

// After RESET the server publishes an empty graph's status (and repeats it in every
// heartbeat); before the fix the subscriber kept every robot and pose it had.
TEST(EstimateSubscriber, ForgetsEverythingWhenANewerStatusReportsAnEmptyGraph) {
  Follower f;
  ASSERT_TRUE(f.lcm.good());
  f.estimate(chunk(10, 0, false, 0, 1, {0, 1, 2}));
  f.estimate(chunk(10, 1, false, 0, 1, {0, 1}));
  f.covariance(0, 2, 10);
  f.status(statusOf(10, 2, 5));  // the tables match the server: nothing forgotten
  f.status(statusOf(9, 0, 0));   // older than the tables (reordered): proves nothing
  EXPECT_EQ(f.sub.robots(), (std::vector<int32_t>{0, 1}));
  EXPECT_TRUE(f.forgotAt.empty());

  f.status(statusOf(11, 0, 0));  // RESET: resetAll(), ++update_seq, status
  EXPECT_TRUE(f.sub.robots().empty());
  EXPECT_TRUE(f.sub.all().empty());
  EXPECT_TRUE(f.sub.latestCovariances().empty());
  EXPECT_EQ(f.forgotAt, std::vector<int64_t>{11});
  EXPECT_EQ(f.sub.forgets(), 1);
  EXPECT_EQ(f.sub.lastStatus().update_seq, 11);

  f.estimate(chunk(10, 1, false, 0, 1, {7}));  // a late delta of the forgotten graph
  f.covariance(1, 7, 10);
  EXPECT_TRUE(f.sub.robots().empty());
  EXPECT_TRUE(f.sub.latestCovariances().empty());
  f.status(statusOf(11, 0, 0));  // the heartbeat repeats it: nothing more to forget
  EXPECT_EQ(f.sub.forgets(), 1);

  f.estimate(chunk(12, 0, false, 0, 1, {0}));  // the new graph
  f.status(statusOf(12, 1, 1));
  EXPECT_EQ(f.sub.robots(), std::vector<int32_t>{0});
  EXPECT_EQ(f.sub.robot(0).poses.size(), 1u);
}

// A server restarted without --resume that gets data before its first heartbeat never
// reports an empty graph, but its status counts fewer robots and poses than the old tables.
TEST(EstimateSubscriber, ForgetsStaleTablesOfARestartedServer) {
  Follower f;
  f.estimate(chunk(100, 0, false, 0, 1, {0, 1, 2, 3, 4}));
  f.estimate(chunk(100, 1, false, 0, 1, {0, 1, 2}));
  f.status(statusOf(100, 2, 8));
  // The new server counts from its start time: a much higher update_seq.
  f.estimate(chunk(5001, 0, false, 0, 1, {0, 1}));
  EXPECT_EQ(f.sub.robot(0).poses.size(), 5u);  // new values over old ones: no way to tell yet
  f.status(statusOf(5001, 1, 2));
  EXPECT_EQ(f.forgotAt, std::vector<int64_t>{5001});
  EXPECT_TRUE(f.sub.robots().empty());
  f.estimate(chunk(5001, 0, true, 0, 1, {0, 1}));  // a full snapshot (REQUEST_ESTIMATE)
  f.estimate(chunk(5002, 0, false, 0, 1, {2}));
  f.status(statusOf(5002, 1, 3));
  EXPECT_EQ(f.sub.robots(), std::vector<int32_t>{0});
  EXPECT_EQ(f.sub.robot(0).poses.size(), 3u);
  EXPECT_EQ(f.sub.forgets(), 1);
}

// estimate_t.full_snapshot: "anything absent no longer exists", a robot with nothing too.
TEST(EstimateSubscriber, AnEmptyFullSnapshotRemovesTheRobot) {
  Follower f;
  f.estimate(chunk(5, 0, false, 0, 1, {0, 1}));
  f.estimate(chunk(5, 3, false, 0, 1, {0}));
  f.estimate(chunk(6, 3, true, 0, 1, {}));
  EXPECT_EQ(f.sub.robots(), std::vector<int32_t>{0});
  EXPECT_EQ(f.sub.robot(3).poses.size(), 0u);
}

}  // namespace
