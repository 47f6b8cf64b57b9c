// Cross-robot landmark sightings through the engine (server/engine_sightings.cpp): a pose of
// robot 1 sighting robot 0's landmarks. Before, the validator refused them ("not supported
// yet"), and robots that shared only landmarks never shared a frame.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <vector>

#include "loopd/ambiguous_factor_t.hpp"
#include "loopd/error_t.hpp"
#include "loopd/estimate_t.hpp"
#include "tests/server/engine_harness.h"

namespace loopd {
namespace {

using client::FactorPublisher;
using client::KeyRef;
using test::EngineHarness;

const Eigen::Matrix2d kInfo2 = Eigen::Matrix2d::Identity() * 100;
const Eigen::Matrix3d kInfoPose2 = Eigen::Vector3d(100, 100, 1000).asDiagonal();

// The world: robot 0 starts at the origin (its frame is the common one), robot 1 at T1 (its
// own frame puts its first pose at the origin). Landmarks L0..L3 belong to robot 0.
struct World2 {
  SE2 T1;
  std::vector<Vec2> landmarks = {{2, 3}, {5, -2}, {-1, 4}, {4, 6}};
  SE2 robot0(int i) const { return SE2(i * 1.0, 0.0, 0.05 * i); }  // in the world
  SE2 odometry1() const { return SE2(0.8, 0.1, -0.1); }
  SE2 robot1Own(int j) const {
    SE2 x;
    for (int k = 0; k < j; ++k) x = x * odometry1();
    return x;
  }
  SE2 robot1(int j) const { return T1 * robot1Own(j); }
};

client::Pose2 pose2(const SE2& x) { return {x.x, x.y, x.theta}; }

struct TwoRobots {
  EngineHarness h;
  FactorPublisher r0, r1;
  World2 w;
  bool bearingRange = false;
  int landmarkRobot = 0;  // the robot id the landmarks' keys name
  explicit TwoRobots(double theta1, bool bearing = false, const char* solver = "isam2",
                     server::Journal* journal = nullptr)
      : TwoRobots(theta1, bearing, EngineHarness::options(solver), journal) {}
  TwoRobots(double theta1, bool bearing, const server::EngineOptions& o,
            server::Journal* journal = nullptr)
      : h(o, journal),
        r0([this](const std::string&, const std::vector<std::uint8_t>& b) { h.sendRaw(b); }, "r0",
           "T_FACTORS"),
        r1([this](const std::string&, const std::vector<std::uint8_t>& b) { h.sendRaw(b); }, "r1",
           "T_FACTORS"),
        bearingRange(bearing) {
    w.T1 = SE2(3, 4, theta1);
  }
  // A sighting of landmark l (robot 0's, or landmarkRobot's) from robot `robot`'s pose i; returns
  // its id.
  std::int64_t sight(FactorPublisher& p, int robot, int i, int l) {
    const SE2 x = robot == 0 ? w.robot0(i) : w.robot1(i);
    const Vec2 z = x.transformTo(w.landmarks[static_cast<size_t>(l)]);
    if (bearingRange)
      return p.bearingRange(KeyRef::pose(robot, i), KeyRef::point(landmarkRobot, l),
                            std::atan2(z.y(), z.x()), z.norm(), kInfo2);
    return p.landmark(KeyRef::pose(robot, i), KeyRef::point(landmarkRobot, l), Eigen::Vector2d(z),
                      kInfo2);
  }
  // Robot 0 walks poses 0..5 and sights every landmark from its first and last pose; robot 1
  // walks its poses 0..5.
  void walk() {
    for (int i = 0; i < 5; ++i) {
      r0.odometry(0, i, i + 1, pose2(w.robot0(i).between(w.robot0(i + 1))), kInfoPose2);
      if (i == 0)
        for (int l = 0; l < 4; ++l) sight(r0, 0, 0, l);
      r0.flush();
    }
    for (int l = 0; l < 4; ++l) sight(r0, 0, 5, l);
    r0.flush();
    for (int j = 0; j < 5; ++j) {
      r1.odometry(1, j, j + 1, pose2(w.odometry1()), kInfoPose2);
      r1.flush();
    }
  }
  int anchoredFactors() const {
    int n = 0;
    for (const auto& f : h.engine.backend().graph().factors()) n += f->size() == 4;
    return n;
  }
  // Robot 1's poses and robot 0's landmarks, as published, against the world.
  void expectWorld(double tol) const {
    for (int j = 0; j <= 5; ++j) {
      std::vector<double> x;
      ASSERT_TRUE(h.engine.commonFramePose(poseKey(static_cast<std::uint64_t>(j), 1), x));
      const SE2 truth = w.robot1(j);
      EXPECT_NEAR(x[0], truth.x, tol) << j;
      EXPECT_NEAR(x[1], truth.y, tol) << j;
      EXPECT_NEAR(std::remainder(x[2] - truth.theta, 2 * M_PI), 0.0, tol) << j;
    }
    for (int l = 0; l < 4; ++l) {
      std::vector<double> p;
      ASSERT_TRUE(h.engine.commonFramePose(
          landmarkKey(static_cast<std::uint64_t>(l), static_cast<std::uint32_t>(landmarkRobot)),
          p));
      EXPECT_NEAR(p[0], w.landmarks[static_cast<size_t>(l)].x(), tol) << l;
      EXPECT_NEAR(p[1], w.landmarks[static_cast<size_t>(l)].y(), tol) << l;
    }
  }
  std::string firstError() const { return h.out.errors.empty() ? "" : h.out.errors.front().reason; }
};

// One landmark leaves the rotation between the frames free: robot 1's sightings of it wait.
// A second landmark fixes the frames; the join starts at the landmarks' alignment, so even a
// half-turn between the frames lands on the world exactly.
void joinsOnTheSecondLandmark(double theta1, bool bearingRange) {
  TwoRobots t(theta1, bearingRange);
  t.walk();
  t.sight(t.r1, 1, 2, 0);
  t.r1.flush();
  t.sight(t.r1, 1, 4, 0);  // the same landmark again
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_FALSE(t.h.engine.robotJoined(1));
  EXPECT_EQ(t.anchoredFactors(), 0);
  EXPECT_EQ(t.h.out.statuses.back().robots_in_common_frame, 0);
  t.sight(t.r1, 1, 3, 1);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_TRUE(t.h.engine.robotJoined(0));
  EXPECT_TRUE(t.h.engine.robotJoined(1));
  EXPECT_EQ(t.anchoredFactors(), 3);
  EXPECT_EQ(t.h.out.statuses.back().robots_in_common_frame, 2);
  EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
  t.expectWorld(1e-6);
  // Later sightings go straight in.
  t.sight(t.r1, 1, 5, 2);
  t.r1.flush();
  EXPECT_EQ(t.anchoredFactors(), 4);
  EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
}

TEST(EngineSightings, PosePointSightingsJoinTwoRobotsOnTheSecondLandmark) {
  joinsOnTheSecondLandmark(1.2, false);
}

TEST(EngineSightings, AHalfTurnBetweenTheFramesIsFoundByTheAlignment) {
  joinsOnTheSecondLandmark(3.0, false);
  joinsOnTheSecondLandmark(-2.9, false);
}

TEST(EngineSightings, BearingRangeSightingsJoinTwoRobots) { joinsOnTheSecondLandmark(2.5, true); }

// Noisy sightings: the joined graph is the single-frame problem, so its optimum is the one of
// the same measurements solved by lm in one frame (robot 1's poses in the world).
TEST(EngineSightings, TheJoinedOptimumIsTheSingleFrameOne) {
  TwoRobots t(2.0, false, "lm");
  t.walk();
  const double nx[3] = {0.03, -0.02, 0.05}, ny[3] = {-0.01, 0.04, -0.03};
  for (int k = 0; k < 3; ++k) {
    const SE2 x = t.w.robot1(k + 2);
    const Vec2 z = x.transformTo(t.w.landmarks[static_cast<size_t>(k)]) + Vec2(nx[k], ny[k]);
    t.r1.landmark(KeyRef::pose(1, k + 2), KeyRef::point(0, k), Eigen::Vector2d(z), kInfo2);
    t.r1.flush();
  }
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  ASSERT_TRUE(t.h.engine.robotJoined(1));
  const double joined = t.h.engine.backend().chi2();
  EXPECT_GT(joined, 0.01);  // the noise does not fit exactly
  // The same measurements as one robot's graph in one frame: robot 1's poses 100+j.
  EngineHarness one("lm");
  FactorPublisher p([&](const std::string&, const std::vector<std::uint8_t>& b) { one.sendRaw(b); },
                    "one", "T_FACTORS");
  const World2& w = t.w;
  for (int i = 0; i < 5; ++i) {
    p.odometry(0, i, i + 1, pose2(w.robot0(i).between(w.robot0(i + 1))), kInfoPose2);
    if (i == 0)
      for (int l = 0; l < 4; ++l)
        p.landmark(KeyRef::pose(0, 0), KeyRef::point(0, l),
                   Eigen::Vector2d(w.robot0(0).transformTo(w.landmarks[static_cast<size_t>(l)])),
                   kInfo2);
    p.flush();
  }
  for (int l = 0; l < 4; ++l)
    p.landmark(KeyRef::pose(0, 5), KeyRef::point(0, l),
               Eigen::Vector2d(w.robot0(5).transformTo(w.landmarks[static_cast<size_t>(l)])),
               kInfo2);
  p.flush();
  // Robot 1's walk hangs off its first sighting: start it at its true pose, unconstrained.
  p.initialValue(KeyRef::pose(0, 100), pose2(w.robot1(0)));
  for (int j = 0; j < 5; ++j) p.odometry(0, 100 + j, 101 + j, pose2(w.odometry1()), kInfoPose2);
  for (int k = 0; k < 3; ++k) {
    const Vec2 z =
        w.robot1(k + 2).transformTo(w.landmarks[static_cast<size_t>(k)]) + Vec2(nx[k], ny[k]);
    p.landmark(KeyRef::pose(0, 102 + k), KeyRef::point(0, k), Eigen::Vector2d(z), kInfo2);
  }
  p.flush();
  EXPECT_TRUE(one.out.errors.empty()) << one.out.errors.front().reason;
  EXPECT_NEAR(joined, one.engine.backend().chi2(), 1e-9 + 1e-6 * joined);
}

// A sighting removed while it waits is gone: it never counts towards the join.
TEST(EngineSightings, ASightingRemovedWhileItWaitsDoesNotCount) {
  TwoRobots t(1.0);
  t.walk();
  const std::int64_t first = t.sight(t.r1, 1, 2, 0);
  t.r1.flush();
  t.r1.remove(first);
  t.r1.flush();
  t.sight(t.r1, 1, 3, 1);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_FALSE(t.h.engine.robotJoined(1));  // only landmark 1 is left
  t.sight(t.r1, 1, 4, 2);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_TRUE(t.h.engine.robotJoined(1));
  EXPECT_EQ(t.anchoredFactors(), 2);
  t.expectWorld(1e-6);
}

// Frames joined by a loop closure take a single sighting at once, and the ones waiting go in
// with the closure.
TEST(EngineSightings, AClosureJoinsTheFramesAndTheWaitingSightingsGoIn) {
  TwoRobots t(0.7);
  t.walk();
  t.sight(t.r1, 1, 2, 0);
  t.r1.flush();
  EXPECT_EQ(t.anchoredFactors(), 0);
  t.r1.loopClosure(KeyRef::pose(0, 2), KeyRef::pose(1, 1),
                   pose2(t.w.robot0(2).between(t.w.robot1(1))), kInfoPose2);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_EQ(t.anchoredFactors(), 2);  // the closure and the sighting
  t.sight(t.r1, 1, 3, 1);
  t.r1.flush();
  EXPECT_EQ(t.anchoredFactors(), 3);
  EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
  t.expectWorld(1e-6);
}

// A sighting of a landmark its owner has not introduced yet does not hold its batch: before,
// the batch waited for the owner's sighting, and every later batch of the robot waited behind
// its poses, until all expired. Now the rest of the batch goes in, the sighting is kept back
// like any other until the frames are joined, and it counts towards joining them once the
// owner has placed the landmark.
TEST(EngineSightings, ASightingOfALandmarkNotIntroducedYetDoesNotHoldItsBatch) {
  TwoRobots t(1.0);
  t.walk();
  t.w.landmarks.push_back({6, 1});  // landmark 4: robot 0 has not sighted it
  t.r1.odometry(1, 5, 6, pose2(t.w.odometry1()), kInfoPose2);
  t.sight(t.r1, 1, 5, 4);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_EQ(t.h.out.statuses.back().batches_held, 0);
  EXPECT_TRUE(t.h.engine.backend().estimate().contains(poseKey(6, 1)));
  EXPECT_FALSE(t.h.engine.backend().estimate().contains(landmarkKey(4, 0)));
  t.r1.odometry(1, 6, 7, pose2(t.w.odometry1()), kInfoPose2);
  t.r1.flush();
  EXPECT_TRUE(t.h.engine.backend().estimate().contains(poseKey(7, 1)));
  EXPECT_EQ(t.anchoredFactors(), 0);
  t.sight(t.r1, 1, 3, 1);  // a second landmark, but robot 0 has not placed 4 yet
  t.r1.flush();
  EXPECT_FALSE(t.h.engine.robotJoined(1));
  t.sight(t.r0, 0, 5, 4);  // now it has: the two landmarks join the frames
  t.r0.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_TRUE(t.h.engine.robotJoined(1));
  EXPECT_EQ(t.anchoredFactors(), 2);
  EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
  t.expectWorld(1e-6);
}

// Once the frames are joined, another robot's sighting introduces the landmark (before, the
// batch was held until the owner sighted it, and expired if it never did): the anchors place
// it in its owner's frame, where the owner's later sighting agrees.
void introducesTheOtherRobotsLandmark(bool bearingRange) {
  TwoRobots t(1.0, bearingRange);
  t.walk();
  t.sight(t.r1, 1, 2, 0);
  t.sight(t.r1, 1, 3, 1);
  t.r1.flush();
  ASSERT_TRUE(t.h.engine.robotJoined(1));
  t.w.landmarks.push_back({6, 1});  // landmark 4, not sighted by robot 0 yet
  t.sight(t.r1, 1, 4, 4);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_EQ(t.h.out.statuses.back().batches_held, 0);
  std::vector<double> p;
  ASSERT_TRUE(t.h.engine.commonFramePose(landmarkKey(4, 0), p));
  EXPECT_NEAR(p[0], 6.0, 1e-6);
  EXPECT_NEAR(p[1], 1.0, 1e-6);
  t.sight(t.r0, 0, 5, 4);
  t.r0.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
  t.expectWorld(1e-6);
}

TEST(EngineSightings, APosePointSightingIntroducesTheOtherRobotsLandmarkOnceJoined) {
  introducesTheOtherRobotsLandmark(false);
}

TEST(EngineSightings, ABearingRangeSightingIntroducesTheOtherRobotsLandmarkOnceJoined) {
  introducesTheOtherRobotsLandmark(true);
}

// A kept-back sighting of a landmark nobody introduced goes in, and places it, when a closure
// joins the frames; so does one that comes in the same batch as the joining closure.
TEST(EngineSightings, AClosureJoiningTheFramesReleasesASightingOfANewLandmark) {
  TwoRobots t(0.7);
  t.walk();
  t.w.landmarks.push_back({6, 1});
  t.w.landmarks.push_back({1, -3});
  t.sight(t.r1, 1, 2, 4);
  t.r1.flush();
  EXPECT_EQ(t.h.out.statuses.back().batches_held, 0);
  EXPECT_FALSE(t.h.engine.backend().estimate().contains(landmarkKey(4, 0)));
  t.r1.loopClosure(KeyRef::pose(0, 2), KeyRef::pose(1, 1),
                   pose2(t.w.robot0(2).between(t.w.robot1(1))), kInfoPose2);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  std::vector<double> p;
  ASSERT_TRUE(t.h.engine.commonFramePose(landmarkKey(4, 0), p));
  EXPECT_NEAR(p[0], 6.0, 1e-6);
  EXPECT_NEAR(p[1], 1.0, 1e-6);
  EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);

  TwoRobots u(-2.0);
  u.walk();
  u.w.landmarks.push_back({6, 1});
  u.sight(u.r1, 1, 3, 4);
  u.r1.loopClosure(KeyRef::pose(0, 2), KeyRef::pose(1, 1),
                   pose2(u.w.robot0(2).between(u.w.robot1(1))), kInfoPose2);
  u.r1.flush();
  EXPECT_TRUE(u.h.out.errors.empty()) << u.firstError();
  EXPECT_EQ(u.h.out.statuses.back().batches_held, 0);
  ASSERT_TRUE(u.h.engine.commonFramePose(landmarkKey(4, 0), p));
  EXPECT_NEAR(p[0], 6.0, 1e-6);
  EXPECT_NEAR(p[1], 1.0, 1e-6);
  EXPECT_LT(u.h.engine.backend().chi2(), 1e-9);
}

// A sighting of a landmark nobody has placed waits in the list of a pair that other sightings
// then join: the alignment takes the placed landmarks only, and the new one is placed after.
// A resumed server replays the same and ends where the live one did.
TEST(EngineSightings, ASightingJoinPlacesANewLandmarkAndAResumeReplaysIt) {
  const std::string path =
      ::testing::TempDir() + "/" + std::to_string(getpid()) + "_sightings.lcmlog";
  std::remove(path.c_str());
  {
    server::Journal j(path, false);
    TwoRobots t(2.2, false, "isam2", &j);
    t.walk();
    t.w.landmarks.push_back({6, 1});
    t.sight(t.r1, 1, 4, 4);
    t.r1.flush();
    t.sight(t.r1, 1, 2, 0);
    t.sight(t.r1, 1, 3, 1);
    t.r1.flush();
    EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
    ASSERT_TRUE(t.h.engine.robotJoined(1));
    EXPECT_EQ(t.anchoredFactors(), 3);
    EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
    std::vector<double> live;
    ASSERT_TRUE(t.h.engine.commonFramePose(landmarkKey(4, 0), live));
    EXPECT_NEAR(live[0], 6.0, 1e-6);
    EXPECT_NEAR(live[1], 1.0, 1e-6);

    EngineHarness resumed("isam2");
    resumed.engine.replay(path, false, nullptr);
    EXPECT_TRUE(resumed.out.errors.empty());
    std::vector<double> again;
    ASSERT_TRUE(resumed.engine.commonFramePose(landmarkKey(4, 0), again));
    EXPECT_NEAR(again[0], live[0], 1e-9);
    EXPECT_NEAR(again[1], live[1], 1e-9);
    EXPECT_EQ(resumed.engine.backend().graph().size(), t.h.engine.backend().graph().size());
  }
  std::remove(path.c_str());
}

// Removing sightings until one landmark is left splits the frames again: robot 1's group gets
// a root prior (the graph stays well posed) and goes on taking its own factors.
TEST(EngineSightings, RemovingSightingsDownToOneLandmarkRerootsTheRobot) {
  TwoRobots t(1.0);
  t.walk();
  t.sight(t.r1, 1, 2, 0);
  const std::int64_t second = t.sight(t.r1, 1, 3, 1);
  t.r1.flush();
  ASSERT_EQ(t.anchoredFactors(), 2);
  const int before = t.h.engine.backend().graph().size();
  t.r1.remove(second);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_EQ(t.anchoredFactors(), 1);
  EXPECT_EQ(t.h.engine.backend().graph().size(), before);  // one sighting out, a root prior in
  t.r1.odometry(1, 5, 6, pose2(t.w.odometry1()), kInfoPose2);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
}

// The x variance of robot `robot`'s latest pose in the latest automatic covariance message.
double latestXVariance(const EngineHarness& h, int robot) {
  for (auto m = h.out.covariances.rbegin(); m != h.out.covariances.rend(); ++m) {
    if (m->request_id != 0) continue;
    size_t at = 0;
    for (int i = 0; i < m->num_keys; ++i) {
      if (m->keys[static_cast<size_t>(i)].robot == robot) return m->values[at];
      at += static_cast<size_t>(m->dims[static_cast<size_t>(i)] * m->dims[static_cast<size_t>(i)]);
    }
  }
  ADD_FAILURE() << "no covariance of robot " << robot;
  return 0.0;
}

// A closure joins the frames; robot 1 then introduces landmarks 4 and 5, robot 0's, which
// robot 0 has not sighted; the closure is removed. Those landmarks fix nothing between the
// frames, so robot 1's group must get a root prior. Before, they counted as two shared points:
// the frames stayed "joined" with nothing fixing the transform, and robot 1's covariance grew
// to about 10^5 m^2. Returns the graph's size before the removal.
int introduceTwoLandmarksAndRemoveTheClosure(TwoRobots& t) {
  t.w.landmarks.push_back({6, 1});   // landmark 4
  t.w.landmarks.push_back({1, -3});  // landmark 5
  const std::int64_t closure =
      t.r1.loopClosure(KeyRef::pose(0, 2), KeyRef::pose(1, 1),
                       pose2(t.w.robot0(2).between(t.w.robot1(1))), kInfoPose2);
  t.r1.flush();
  t.sight(t.r1, 1, 2, 4);
  t.sight(t.r1, 1, 3, 5);
  t.r1.flush();
  EXPECT_TRUE(t.h.engine.robotJoined(1));
  const int anchored = t.anchoredFactors();
  const int before = t.h.engine.backend().graph().size();
  t.r1.remove(closure);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_EQ(t.anchoredFactors(), anchored - 1);
  EXPECT_EQ(t.h.engine.backend().graph().size(), before);  // the closure out, a root prior in
  EXPECT_LT(latestXVariance(t.h, 1), 1.0);
  return before;
}

// Once two sightings fix landmarks 4 and 5 in robot 0's group, robot 1 is joined to it again
// and its root prior goes.
void expectRejoined(const TwoRobots& t, int before) {
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_EQ(t.h.engine.backend().graph().size(), before + 2 - 1);  // two sightings, no prior
  EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
  t.expectWorld(1e-6);
}

// ... and once robot 0 sights them, they join the frames again.
TEST(EngineSightings, LandmarksOnlyOneRobotSightsDoNotKeepTheFramesJoined) {
  TwoRobots t(0.7);
  t.walk();
  const int before = introduceTwoLandmarksAndRemoveTheClosure(t);
  t.sight(t.r0, 0, 5, 4);
  t.sight(t.r0, 0, 5, 5);
  t.r0.flush();
  expectRejoined(t, before);
}

// With a third robot: robot 2, joined to robot 0 by a closure, sights the two landmarks after
// robot 1 was split off. They are then fixed in robot 0's group and join robot 1 to it
// (before, robot 1's root prior stayed: two root priors in one group).
TEST(EngineSightings, SightingsFromTheOwnersGroupJoinARobotSplitOffAgain) {
  TwoRobots t(0.7);
  FactorPublisher r2(
      [&t](const std::string&, const std::vector<std::uint8_t>& b) { t.h.sendRaw(b); }, "r2",
      "T_FACTORS");
  const SE2 t2(-2, 1, -0.4);
  auto robot2 = [&](int j) { return t2 * t.w.robot1Own(j); };
  t.walk();
  for (int j = 0; j < 5; ++j) {
    r2.odometry(2, j, j + 1, pose2(t.w.odometry1()), kInfoPose2);
    r2.flush();
  }
  r2.loopClosure(KeyRef::pose(0, 1), KeyRef::pose(2, 2), pose2(t.w.robot0(1).between(robot2(2))),
                 kInfoPose2);
  r2.flush();
  ASSERT_TRUE(t.h.engine.robotJoined(2));
  const int before = introduceTwoLandmarksAndRemoveTheClosure(t);
  for (int l = 4; l <= 5; ++l) {
    const Vec2 z = robot2(l - 1).transformTo(t.w.landmarks[static_cast<size_t>(l)]);
    r2.landmark(KeyRef::pose(2, l - 1), KeyRef::point(0, l), Eigen::Vector2d(z), kInfo2);
  }
  r2.flush();
  expectRejoined(t, before);
}

// The frames were joined by landmarks 0 and 4; robot 0's one sighting of landmark 4 is removed.
// Landmark 4 then fixes nothing between the frames: robot 1 is rerooted as when its own
// sightings go (before, removing the owner's sighting regrouped nothing).
TEST(EngineSightings, RemovingTheOwnersOnlySightingOfALandmarkRerootsTheRobot) {
  TwoRobots t(1.0);
  t.walk();
  t.w.landmarks.push_back({6, 1});  // landmark 4
  const std::int64_t tie = t.sight(t.r0, 0, 3, 4);
  t.r0.flush();
  t.sight(t.r1, 1, 2, 0);
  t.sight(t.r1, 1, 3, 4);
  t.r1.flush();
  ASSERT_TRUE(t.h.engine.robotJoined(1));
  ASSERT_EQ(t.anchoredFactors(), 2);
  const int before = t.h.engine.backend().graph().size();
  t.r0.remove(tie);
  t.r0.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_EQ(t.h.engine.backend().graph().size(), before);  // the sighting out, a root prior in
  EXPECT_LT(latestXVariance(t.h, 1), 1.0);
  t.r1.odometry(1, 5, 6, pose2(t.w.odometry1()), kInfoPose2);
  t.r1.flush();
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
}

server::EngineOptions withNamespace100() {
  server::EngineOptions o = EngineHarness::options("isam2");
  o.landmarkNamespaces = {100};
  return o;
}

// The published estimate of robot `robot`'s landmark `l` (the latest message that has it).
const loopd::estimate_t* latestEstimateWith(const EngineHarness& h, int robot, int l) {
  for (auto e = h.out.estimates.rbegin(); e != h.out.estimates.rend(); ++e)
    if (e->robot == robot)
      for (std::int64_t i : e->landmark_indices)
        if (i == l) return &*e;
  return nullptr;
}

// A landmark namespace (a shared tag map, robot id 100, which never has poses): the first
// robot to sight one of its landmarks holds them all in its frame, and other robots' sightings
// join their frames to it as sightings of that robot's landmarks do. Before, nothing joined
// robot 100's frame (it has no poses), and every sighting of its landmarks was kept back for
// good; the workaround was to give the tags to one robot.
void namespaceAdoptedBy(int firstSighter) {
  TwoRobots t(1.3, false, withNamespace100());
  t.landmarkRobot = 100;
  if (firstSighter == 0) {
    t.walk();  // robot 0 sights every tag from poses 0 and 5
    t.sight(t.r1, 1, 2, 0);
    t.sight(t.r1, 1, 3, 1);
    t.r1.flush();
  } else {
    for (int i = 0; i < 5; ++i) {
      t.r0.odometry(0, i, i + 1, pose2(t.w.robot0(i).between(t.w.robot0(i + 1))), kInfoPose2);
      t.r0.flush();
    }
    for (int j = 0; j < 5; ++j) {
      t.r1.odometry(1, j, j + 1, pose2(t.w.odometry1()), kInfoPose2);
      for (int l = 0; l < 4; ++l) t.sight(t.r1, 1, j + 1, l);
      t.r1.flush();
    }
    EXPECT_EQ(t.anchoredFactors(), 0);  // robot 1's own tags now
    t.sight(t.r0, 0, 2, 0);
    t.r0.flush();
    EXPECT_FALSE(t.h.engine.robotJoined(0));  // one tag: kept back
    t.sight(t.r0, 0, 4, 1);
    t.r0.flush();
  }
  EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
  ASSERT_TRUE(t.h.engine.robotJoined(0));
  ASSERT_TRUE(t.h.engine.robotJoined(1));
  EXPECT_EQ(t.anchoredFactors(), 2);
  EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
  t.expectWorld(1e-6);  // tags in the common frame (robot 0's, the world's)
  // Published as robot 100's landmarks, in the common frame.
  const loopd::estimate_t* e = latestEstimateWith(t.h, 100, 3);
  ASSERT_NE(e, nullptr);
  EXPECT_TRUE(e->common_frame);
  EXPECT_EQ(e->frame_robot, 0);
  EXPECT_EQ(e->num_poses, 0);
  for (size_t i = 0; i < e->landmark_indices.size(); ++i) {
    const Vec2& truth = t.w.landmarks[static_cast<size_t>(e->landmark_indices[i])];
    EXPECT_NEAR(e->landmarks[i][0], truth.x(), 1e-6);
    EXPECT_NEAR(e->landmarks[i][1], truth.y(), 1e-6);
  }
}

TEST(EngineSightings, ALandmarkNamespaceLivesInItsFirstSightersFrame) { namespaceAdoptedBy(0); }

TEST(EngineSightings, ALandmarkNamespaceAdoptedByTheOtherRobotJoinsTheSame) {
  namespaceAdoptedBy(1);
}

// A landmark namespace has no poses, and its landmarks no frame of their own for a prior.
TEST(EngineSightings, ALandmarkNamespaceRefusesPosesAndPriors) {
  TwoRobots t(1.3, false, withNamespace100());
  t.landmarkRobot = 100;
  t.walk();
  const int size = t.h.engine.backend().graph().size();
  t.r1.odometry(100, 0, 1, pose2(t.w.odometry1()), kInfoPose2);
  t.r1.flush();
  ASSERT_EQ(t.h.out.errors.size(), 2u);  // one per pose key
  for (const auto& e : t.h.out.errors) {
    EXPECT_EQ(e.code, loopd::error_t::WRONG_KEY_KIND);
    EXPECT_NE(e.reason.find("landmark namespace"), std::string::npos) << e.reason;
  }
  loopd::factor_t prior = client::landmarkFactor(KeyRef::pose(1, 0), KeyRef::point(100, 9),
                                                 Eigen::Vector2d(1, 2), kInfo2);
  prior.type = loopd::factor_t::PRIOR_POINT2;
  prior.role = loopd::factor_t::ROLE_PRIOR;
  prior.keys.erase(prior.keys.begin());
  prior.num_keys = 1;
  prior.id = -1;  // the publisher's next
  t.r1.odometry(1, 5, 6, pose2(t.w.odometry1()), kInfoPose2);
  t.r1.factor(prior);
  t.r1.flush();
  ASSERT_EQ(t.h.out.errors.size(), 3u);
  EXPECT_EQ(t.h.out.errors.back().code, loopd::error_t::INVALID_FIELD);
  EXPECT_NE(t.h.out.errors.back().reason.find("placed by sightings only"), std::string::npos)
      << t.h.out.errors.back().reason;
  EXPECT_EQ(t.h.engine.backend().graph().size(), size);  // neither batch applied
}

// The adopting robot's ambiguous sighting of a namespace's landmarks is one in its own frame
// (before the validator knew namespaces it read as a link between robots 0 and 100, whose
// frames nothing joined, and refused it); a resumed server with the same namespace replays the
// adoption and ends where the live one did.
TEST(EngineSightings, ALandmarkNamespaceTakesAmbiguousSightingsAndResumes) {
  const std::string path =
      ::testing::TempDir() + "/" + std::to_string(getpid()) + "_namespace.lcmlog";
  std::remove(path.c_str());
  {
    server::EngineOptions o = withNamespace100();
    o.idleSeconds = 0;  // idle() optimizes at once
    server::Journal j(path, false);
    TwoRobots t(1.3, false, o, &j);
    t.landmarkRobot = 100;
    t.walk();
    const Vec2 z = t.w.robot0(3).transformTo(t.w.landmarks[1]);
    std::vector<loopd::factor_t> alternatives;
    for (int l : {1, 2})
      alternatives.push_back(client::landmarkFactor(KeyRef::pose(0, 3), KeyRef::point(100, l),
                                                    Eigen::Vector2d(z), kInfo2));
    t.r0.ambiguous(loopd::ambiguous_factor_t::MULTI_ASSOCIATION, alternatives, false);
    t.r0.flush();
    EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
    t.sight(t.r1, 1, 2, 0);
    t.sight(t.r1, 1, 3, 1);
    t.r1.flush();
    EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
    ASSERT_TRUE(t.h.engine.robotJoined(1));
    EXPECT_EQ(t.anchoredFactors(), 2);

    EngineHarness resumed(o, nullptr);
    resumed.engine.replay(path, false, nullptr);
    EXPECT_TRUE(resumed.out.errors.empty());
    // The wrong alternative leaves a residual: compare the converged estimates.
    t.h.engine.idle();
    resumed.engine.idle();
    EXPECT_EQ(resumed.engine.backend().graph().size(), t.h.engine.backend().graph().size());
    for (const Key k : {landmarkKey(3, 100), poseKey(5, 1)}) {
      std::vector<double> live, again;
      ASSERT_TRUE(t.h.engine.commonFramePose(k, live));
      ASSERT_TRUE(resumed.engine.commonFramePose(k, again));
      for (size_t i = 0; i < live.size(); ++i) EXPECT_NEAR(again[i], live[i], 1e-6) << i;
    }
  }
  std::remove(path.c_str());
}

// 3D: two landmarks leave the rotation about the line through them free; the third fixes it.
TEST(EngineSightings, ThreeDimensionalSightingsJoinOnTheThirdLandmark) {
  EngineHarness h("isam2");
  auto sink = [&](const std::string&, const std::vector<std::uint8_t>& b) { h.sendRaw(b); };
  FactorPublisher r0(sink, "r0", "T_FACTORS"), r1(sink, "r1", "T_FACTORS");
  const Mat6 info = Mat6::Identity() * 100;
  const Eigen::Matrix3d infoP = Eigen::Matrix3d::Identity() * 100;
  const std::vector<Vec3> L = {{2, 3, 1}, {5, -2, 0.5}, {-1, 4, 2}, {4, 6, -1}};
  auto pose3 = [](const SE3& x) {
    client::Pose3 p;
    p.t = x.t;
    p.q = Eigen::Quaterniond(x.R);
    return p;
  };
  const SE3 step(Eigen::AngleAxisd(0.1, Vec3(0.2, 0.3, 1).normalized()).toRotationMatrix(),
                 Vec3(1, 0.1, 0.05));
  const SE3 T1(Eigen::AngleAxisd(2.6, Vec3(1, -2, 0.5).normalized()).toRotationMatrix(),
               Vec3(3, 4, -1));
  auto robot0 = [&](int i) {
    SE3 x;
    for (int k = 0; k < i; ++k) x = x * step;
    return x;
  };
  auto robot1 = [&](int j) { return T1 * robot0(j); };
  for (int i = 0; i < 4; ++i) {
    r0.odometry(0, i, i + 1, pose3(step), info);
    if (i == 0)
      for (int l = 0; l < 4; ++l)
        r0.landmark(KeyRef::pose(0, 0), KeyRef::point(0, l),
                    Eigen::Vector3d(L[static_cast<size_t>(l)]), infoP);
    r0.flush();
    r1.odometry(1, i, i + 1, pose3(step), info);
    r1.flush();
  }
  for (int l = 0; l < 3; ++l) {
    r1.landmark(KeyRef::pose(1, l + 1), KeyRef::point(0, l),
                Eigen::Vector3d(robot1(l + 1).transformTo(L[static_cast<size_t>(l)])), infoP);
    r1.flush();
    EXPECT_EQ(h.engine.robotJoined(1), l == 2) << l;
  }
  // Joined: robot 1 introduces a landmark of robot 0's, placed in robot 0's frame.
  const Vec3 fifth(1, -2, 3);
  r1.landmark(KeyRef::pose(1, 4), KeyRef::point(0, 7),
              Eigen::Vector3d(robot1(4).transformTo(fifth)), infoP);
  r1.flush();
  EXPECT_TRUE(h.out.errors.empty()) << h.out.errors.front().reason;
  EXPECT_EQ(h.out.statuses.back().batches_held, 0);
  std::vector<double> p;
  ASSERT_TRUE(h.engine.commonFramePose(landmarkKey(7, 0), p));
  EXPECT_NEAR((Vec3(p[0], p[1], p[2]) - fifth).norm(), 0.0, 1e-6);
  EXPECT_LT(h.engine.backend().chi2(), 1e-9);
  for (int j = 0; j <= 4; ++j) {
    std::vector<double> x;
    ASSERT_TRUE(h.engine.commonFramePose(poseKey(static_cast<std::uint64_t>(j), 1), x));
    EXPECT_NEAR((Vec3(x[0], x[1], x[2]) - robot1(j).t).norm(), 0.0, 1e-6) << j;
  }
}

// Ambiguous cross-robot sightings (which of two landmarks of robot 0 did robot 1 see?) are
// refused while the frames are not joined, as inter-robot alternatives are, and taken once
// sightings have joined them: mh picks the true landmark.
TEST(EngineSightings, AmbiguousCrossRobotSightingsOnceTheFramesAreJoined) {
  for (const char* solver : {"isam2", "mh"}) {
    SCOPED_TRACE(solver);
    TwoRobots t(1.0, false, solver);
    t.walk();
    const Vec2 z = t.w.robot1(3).transformTo(t.w.landmarks[1]);
    auto landmark1or2 = [&] {
      std::vector<loopd::factor_t> alternatives;
      for (int l : {1, 2})
        alternatives.push_back(client::landmarkFactor(KeyRef::pose(1, 3), KeyRef::point(0, l),
                                                      Eigen::Vector2d(z), kInfo2));
      t.r1.ambiguous(loopd::ambiguous_factor_t::MULTI_ASSOCIATION, alternatives, false);
      t.r1.flush();
    };
    landmark1or2();
    ASSERT_EQ(t.h.out.errors.size(), 1u);
    EXPECT_EQ(t.h.out.errors[0].code, loopd::error_t::INVALID_FIELD);
    EXPECT_NE(t.firstError().find("whose frames no certain factor has joined yet"),
              std::string::npos)
        << t.firstError();
    t.h.out.errors.clear();
    t.sight(t.r1, 1, 2, 0);
    t.sight(t.r1, 1, 4, 3);
    t.r1.flush();
    ASSERT_TRUE(t.h.engine.robotJoined(1));
    landmark1or2();
    t.h.engine.idle();
    EXPECT_TRUE(t.h.out.errors.empty()) << t.firstError();
    // The two sightings that joined the frames, and mh's chosen alternative or, flattened,
    // both alternatives.
    EXPECT_EQ(t.anchoredFactors(), std::string(solver) == "mh" ? 3 : 4);
    if (std::string(solver) == "mh") {
      EXPECT_LT(t.h.engine.backend().chi2(), 1e-9);
    }
  }
}

}  // namespace
}  // namespace loopd
