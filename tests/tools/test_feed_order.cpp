// tools/common/feed_order.h: which robot plays which pose, in which order, and when each edge
// is due (what loopd-feed and the server benchmarks publish).
#include <gtest/gtest.h>

#include <stdexcept>
#include <string>

#include "tools/common/feed_order.h"

namespace loopd::tools {
namespace {

// robot/kind/index, for comparing wire keys.
std::string name(const loopd::key_t& k) {
  return std::to_string(k.robot) + (k.kind == loopd::key_t::POSE ? " pose " : " landmark ") +
         std::to_string(k.index);
}

// Poses 0..5 (listed out of order: the feed sorts by id), odometry along them, the loop
// closure 4 -> 1 and a sighting of landmark 7 from pose 2.
io::Dataset sixPoses() {
  io::Dataset ds;
  ds.path = "six.g2o";
  for (std::int64_t id : {3, 0, 5, 1, 4, 2}) ds.poses.push_back({io::VertexType::SE2, id});
  auto edge = [&](io::EdgeType t, std::int64_t from, std::int64_t to) {
    io::Edge e;
    e.type = t;
    e.from = from;
    e.to = to;
    e.information.setIdentity();
    e.index = static_cast<int>(ds.edges.size());
    ds.edges.push_back(e);
  };
  for (int i = 0; i < 5; ++i) edge(io::EdgeType::BetweenSE2, i, i + 1);
  edge(io::EdgeType::BetweenSE2, 4, 1);
  edge(io::EdgeType::PosePoint2, 2, 7);
  return ds;
}

TEST(FeedOrder, SegmentsOneAfterTheOtherOrRoundRobin) {
  const io::Dataset ds = sixPoses();
  const FeedOrder inTurn(ds, -1, 2, false);
  EXPECT_EQ(inTurn.poses(), (std::vector<std::int64_t>{0, 1, 2, 3, 4, 5}));
  const FeedOrder mixed(ds, -1, 2, true);
  EXPECT_EQ(mixed.poses(), (std::vector<std::int64_t>{0, 3, 1, 4, 2, 5}));
  EXPECT_EQ(mixed.robots(), 2);
  EXPECT_EQ(mixed.robotOf(2), 0);
  EXPECT_EQ(mixed.robotOf(3), 1);
  EXPECT_EQ(FeedOrder(ds, -1, 50, false).robots(), 6);  // never more robots than poses
}

TEST(FeedOrder, EachRobotStartsAtItsFirstPoseInFeedOrder) {
  const io::Dataset ds = sixPoses();
  auto starts = [](const FeedOrder& f) {
    std::vector<bool> s;
    for (size_t i = 0; i < f.poses().size(); ++i) s.push_back(f.startsItsRobot(i));
    return s;
  };
  EXPECT_EQ(starts(FeedOrder(ds, -1, 2, false)), (std::vector<bool>{1, 0, 0, 1, 0, 0}));
  EXPECT_EQ(starts(FeedOrder(ds, -1, 2, true)),
            (std::vector<bool>{1, 1, 0, 0, 0, 0}));  // 0 3 1 4 2 5
  EXPECT_EQ(starts(FeedOrder(ds, -1, 3, true)), (std::vector<bool>{1, 1, 1, 0, 0, 0}));
  EXPECT_THROW(FeedOrder(ds, -1, 1, false).startsItsRobot(6), std::out_of_range);
}

TEST(FeedOrder, AnEdgeIsDueWithItsLastPose) {
  const io::Dataset ds = sixPoses();
  const FeedOrder mixed(ds, -1, 2, true);  // 0 3 1 4 2 5
  EXPECT_EQ(mixed.dueAt(ds.edges[0]), 2);  // 0 -> 1
  EXPECT_EQ(mixed.dueAt(ds.edges[2]), 4);  // 2 -> 3
  EXPECT_EQ(mixed.dueAt(ds.edges[5]), 3);  // 4 -> 1
  EXPECT_EQ(mixed.dueAt(ds.edges[6]), 4);  // sighting from 2: its landmark id is no pose
  const FeedOrder firstFour(ds, 4, 1, false);
  EXPECT_EQ(firstFour.dueAt(ds.edges[2]), 3);
  EXPECT_EQ(firstFour.dueAt(ds.edges[3]), -1);  // 3 -> 4: pose 4 is not fed
}

TEST(FeedOrder, FactorsNameTheirRobotsFrames) {
  const io::Dataset ds = sixPoses();
  const FeedOrder inTurn(ds, -1, 2, false);  // robot 0: 0 1 2, robot 1: 3 4 5
  const loopd::factor_t across = inTurn.factor(ds.edges[2], 10);
  EXPECT_EQ(across.role, loopd::factor_t::ROLE_LOOP_CLOSURE);  // robot 10's 2 -> robot 11's 3
  ASSERT_EQ(across.keys.size(), 2u);
  EXPECT_EQ(name(across.keys[0]), "10 pose 2");
  EXPECT_EQ(name(across.keys[1]), "11 pose 3");
  // The boundary's odometry goes as a closure, trusted as loopd-solve trusts odometry.
  EXPECT_EQ(across.robust, "none");
  EXPECT_EQ(inTurn.factor(ds.edges[3]).role, loopd::factor_t::ROLE_ODOMETRY);
  EXPECT_EQ(inTurn.factor(ds.edges[3]).robust, "");
  EXPECT_EQ(inTurn.factor(ds.edges[5]).robust, "");  // a closure: 4 -> 1
  const loopd::factor_t sighting = inTurn.factor(ds.edges[6]);
  EXPECT_EQ(name(sighting.keys[1]), "0 landmark 7");
}

// Odometry is one robot's poses next to each other in id order, as loopd-solve reads files:
// a file keeping every second pose still has odometry.
TEST(FeedOrder, OdometryJoinsNeighboursInIdOrder) {
  io::Dataset ds = sixPoses();
  for (auto& v : ds.poses) v.id *= 2;
  for (auto& e : ds.edges) {
    e.from *= 2;
    if (e.type != io::EdgeType::PosePoint2) e.to *= 2;
  }
  const FeedOrder one(ds, -1, 1, false);
  for (int i = 0; i < 5; ++i)
    EXPECT_EQ(one.factor(ds.edges[i]).role, loopd::factor_t::ROLE_ODOMETRY);
  EXPECT_EQ(one.factor(ds.edges[5]).role, loopd::factor_t::ROLE_LOOP_CLOSURE);  // 8 -> 2
  const FeedOrder two(ds, -1, 2, false);  // robot 0: 0 2 4, robot 1: 6 8 10
  EXPECT_EQ(two.factor(ds.edges[2]).role, loopd::factor_t::ROLE_LOOP_CLOSURE);  // across robots
}

// Adds a sighting of `landmark` from `pose`.
void sight(io::Dataset& ds, std::int64_t pose, std::int64_t landmark) {
  ds.edges.push_back(ds.edges[6]);
  ds.edges.back().from = pose;
  ds.edges.back().to = landmark;
  ds.edges.back().index = static_cast<int>(ds.edges.size()) - 1;
}

// Landmark 7 sighted from poses 2 and 4: one robot's, or (cut in two) two robots', which then
// share it (the second robot's sightings are cross-robot ones); a pose not fed sights nothing.
TEST(FeedOrder, SaysWhichLandmarksMoreThanOneRobotSights) {
  io::Dataset ds = sixPoses();
  sight(ds, 4, 7);
  EXPECT_TRUE(FeedOrder(ds, -1, 1, false).sharedLandmarks(ds).empty());
  EXPECT_EQ(FeedOrder(ds, -1, 2, false).sharedLandmarks(ds), (std::vector<std::int64_t>{7}));
  EXPECT_EQ(FeedOrder(ds, -1, 2, true).sharedLandmarks(ds), (std::vector<std::int64_t>{7}));
  EXPECT_TRUE(FeedOrder(ds, 4, 2, false).sharedLandmarks(ds).empty());  // pose 4 not fed
}

// Landmark 7 sighted from poses 4 and 2 (in that file order): it belongs to the robot whose
// pose sights it first in feed order, and every sighting of it names that robot's landmark.
TEST(FeedOrder, ALandmarkIsItsFirstSightersAndEverySightingSaysSo) {
  io::Dataset ds = sixPoses();
  ds.edges[6].from = 4;
  sight(ds, 2, 7);
  const io::Edge &from4 = ds.edges[6], &from2 = ds.edges[7];
  // Robot 0: 0 1 2, robot 1: 3 4 5, in turn: pose 2 (robot 0) sights it first.
  const FeedOrder inTurn(ds, -1, 2, false);
  EXPECT_EQ(inTurn.landmarkOwner(7), 0);
  EXPECT_EQ(name(inTurn.factor(from2, 10).keys[0]), "10 pose 2");
  EXPECT_EQ(name(inTurn.factor(from2, 10).keys[1]), "10 landmark 7");
  const loopd::factor_t across = inTurn.factor(from4, 10);  // robot 11's pose, 10's landmark
  EXPECT_EQ(across.role, loopd::factor_t::ROLE_LANDMARK);
  EXPECT_EQ(name(across.keys[0]), "11 pose 4");
  EXPECT_EQ(name(across.keys[1]), "10 landmark 7");
  EXPECT_LE(inTurn.dueAt(from2), inTurn.dueAt(from4));  // the owner's first goes out first
  // Round-robin, 0 3 1 4 2 5: pose 4 (robot 1) sights it first.
  const FeedOrder mixed(ds, -1, 2, true);
  EXPECT_EQ(mixed.landmarkOwner(7), 1);
  EXPECT_EQ(name(mixed.factor(from4).keys[0]), "1 pose 4");
  EXPECT_EQ(name(mixed.factor(from4).keys[1]), "1 landmark 7");
  EXPECT_EQ(name(mixed.factor(from2).keys[0]), "0 pose 2");
  EXPECT_EQ(name(mixed.factor(from2).keys[1]), "1 landmark 7");
  EXPECT_LT(mixed.dueAt(from4), mixed.dueAt(from2));
  // One robot: its own, as before.
  EXPECT_EQ(name(FeedOrder(ds, -1, 1, false).factor(from4).keys[1]), "0 landmark 7");
  EXPECT_THROW(inTurn.landmarkOwner(8), std::out_of_range);  // nobody sights it
}

// A shared landmark map (loopd-feed --landmark-owner R): every landmark is robot R's, even one
// only another robot sights, and that robot's sightings of it are cross-robot ones.
TEST(FeedOrder, AFixedOwnerTakesEveryLandmark) {
  io::Dataset ds = sixPoses();
  ds.edges[6].from = 4;  // only robot 1 (poses 3 4 5) sights landmark 7
  const FeedOrder owned(ds, -1, 2, false, 0);
  EXPECT_EQ(owned.landmarkOwner(7), 0);
  EXPECT_EQ(name(owned.factor(ds.edges[6]).keys[0]), "1 pose 4");
  EXPECT_EQ(name(owned.factor(ds.edges[6]).keys[1]), "0 landmark 7");
  EXPECT_EQ(FeedOrder(ds, -1, 2, false).landmarkOwner(7), 1);  // by default its sighter's
  EXPECT_EQ(owned.landmarksOnlyOthersSight(ds), (std::vector<std::int64_t>{7}));
  EXPECT_TRUE(FeedOrder(ds, -1, 2, false).landmarksOnlyOthersSight(ds).empty());
  EXPECT_TRUE(FeedOrder(ds, -1, 2, false, 1).landmarksOnlyOthersSight(ds).empty());
  EXPECT_THROW(FeedOrder(ds, -1, 2, false, 2), std::invalid_argument);
  EXPECT_THROW(FeedOrder(ds, 1, 2, false, 1), std::invalid_argument);  // one pose: one robot
  // A landmark namespace (loopd-feed --landmark-namespace N): a robot id without poses.
  const FeedOrder tags(ds, -1, 2, false, 100, true);
  EXPECT_EQ(name(tags.factor(ds.edges[6]).keys[1]), "100 landmark 7");
  EXPECT_THROW(FeedOrder(ds, -1, 2, false, 1, true), std::invalid_argument);
}

// Eight poses in two robots round-robin, 0 4 1 5 2 6 3 7; landmark 9 sighted from 4, 1 and 3.
// With --poses 4 the first sighter (4) is not fed and does not count: the robots are 0 1 and
// 2 3, fed 0 2 1 3, and pose 1 (robot 0) sights it first.
TEST(FeedOrder, APoseNotFedOwnsNoLandmark) {
  io::Dataset ds = sixPoses();
  for (std::int64_t id : {6, 7}) ds.poses.push_back({io::VertexType::SE2, id});
  ds.edges[6].from = 4;
  ds.edges[6].to = 9;
  sight(ds, 1, 9);
  sight(ds, 3, 9);
  const io::Edge &from1 = ds.edges[7], &from3 = ds.edges[8];
  const FeedOrder all(ds, -1, 2, true);
  EXPECT_EQ(all.poses(), (std::vector<std::int64_t>{0, 4, 1, 5, 2, 6, 3, 7}));
  EXPECT_EQ(all.landmarkOwner(9), 1);
  EXPECT_EQ(name(all.factor(from1).keys[0]), "0 pose 1");
  EXPECT_EQ(name(all.factor(from1).keys[1]), "1 landmark 9");
  EXPECT_EQ(name(all.factor(from3, 5).keys[1]), "6 landmark 9");
  const FeedOrder four(ds, 4, 2, true);
  EXPECT_EQ(four.poses(), (std::vector<std::int64_t>{0, 2, 1, 3}));
  EXPECT_EQ(four.landmarkOwner(9), 0);
  EXPECT_EQ(name(four.factor(from1).keys[1]), "0 landmark 9");
  EXPECT_EQ(name(four.factor(from3).keys[0]), "1 pose 3");
  EXPECT_EQ(name(four.factor(from3).keys[1]), "0 landmark 9");
  EXPECT_EQ(four.sharedLandmarks(ds), (std::vector<std::int64_t>{9}));
}

// A HYPOTHESES group goes out whole at its last alternative's step (loopd-feed), so its
// sightings count from there: robot 1's plain sighting of 7 from pose 3 is published before
// the group {1 -> 7, 5 -> 8} (due with pose 5), and robot 1 owns 7 though pose 1 comes first.
TEST(FeedOrder, AGroupsSightingsCountWhenTheGroupGoesOut) {
  io::Dataset ds = sixPoses();
  ds.edges[6].from = 3;  // plain: 3 -> 7
  sight(ds, 1, 7);       // the group: 1 -> 7, 5 -> 8
  sight(ds, 5, 8);
  ds.hypotheses.push_back({7, 2, false, 9});
  const FeedOrder inTurn(ds, -1, 2, false);  // robot 0: 0 1 2, robot 1: 3 4 5
  EXPECT_EQ(inTurn.dueAt(ds, ds.hypotheses[0]), 5);
  EXPECT_EQ(inTurn.landmarkOwner(7), 1);
  EXPECT_EQ(name(inTurn.factor(ds.edges[7]).keys[0]), "0 pose 1");
  EXPECT_EQ(name(inTurn.factor(ds.edges[7]).keys[1]), "1 landmark 7");
  // --poses 5: the group (pose 5) never goes out, and its sightings count after all others.
  const FeedOrder five(ds, 5, 2, false);  // robot 0: 0 1 2, robot 1: 3 4
  EXPECT_EQ(five.dueAt(ds, ds.hypotheses[0]), -1);
  EXPECT_EQ(five.landmarkOwner(7), 1);
  EXPECT_THROW(five.landmarkOwner(8), std::out_of_range);
  // Without the group, pose 1 (robot 0) is the first to sight 7.
  ds.hypotheses.clear();
  EXPECT_EQ(FeedOrder(ds, -1, 2, false).landmarkOwner(7), 0);
}

TEST(FeedOrder, AFileWithoutPosesIsRefused) {
  io::Dataset empty;
  empty.path = "empty.g2o";
  EXPECT_THROW(FeedOrder(empty, -1, 1, false), std::runtime_error);
  EXPECT_THROW(FeedOrder(sixPoses(), 0, 1, false), std::runtime_error);
}

}  // namespace
}  // namespace loopd::tools
