// Which robots share a frame (server/frame_groups.h): a between factor joins on its own,
// sightings once they name enough distinct landmarks fixed in both frames.
#include "server/frame_groups.h"

#include <gtest/gtest.h>

using namespace loopd;
using namespace loopd::server;

namespace {

InterEdge between(std::uint32_t r, std::uint32_t s) { return {r, s, 0, 0}; }
InterEdge sighting(std::uint32_t r, std::uint32_t s, std::uint64_t landmark, int needed = 2) {
  return {r, s, landmarkKey(landmark, s), needed};
}

// Every landmark tied to its owner's frame (as when the owner sights each one too).
bool allTied(Key) { return true; }
bool noneTied(Key) { return false; }

}  // namespace

TEST(FrameGroups, ABetweenFactorJoinsOnItsOwn) {
  const auto g = frameGroupsOf({{1, between(2, 1)}, {2, between(3, 4)}}, allTied);
  EXPECT_EQ(g.at(1), 1u);
  EXPECT_EQ(g.at(2), 1u);
  EXPECT_EQ(g.at(3), 3u);
  EXPECT_EQ(g.at(4), 3u);
}

TEST(FrameGroups, SightingsJoinOnceTheyNameEnoughDistinctLandmarks) {
  std::map<FactorId, InterEdge> edges = {{1, sighting(0, 1, 5)}, {2, sighting(0, 1, 5)}};
  EXPECT_NE(frameGroupsOf(edges, allTied).at(1), 0u);  // one landmark, twice: the rotation is free
  edges[3] = sighting(1, 0, 9);  // the other way round counts for the same pair
  EXPECT_EQ(frameGroupsOf(edges, allTied).at(1), 0u);
  // 3D: three landmarks.
  std::map<FactorId, InterEdge> e3 = {{1, sighting(2, 3, 1, 3)}, {2, sighting(2, 3, 2, 3)}};
  EXPECT_NE(frameGroupsOf(e3, allTied).at(3), 2u);
  e3[3] = sighting(2, 3, 3, 3);
  EXPECT_EQ(frameGroupsOf(e3, allTied).at(3), 2u);
}

TEST(FrameGroups, ExtraJoinsAndChains) {
  const auto g = frameGroupsOf({{1, between(0, 1)}}, noneTied, {{1, 2}, {3, 2}});
  for (std::uint32_t r = 0; r <= 3; ++r) EXPECT_EQ(g.at(r), 0u) << r;
}

// Robot 1 sights two landmarks of robot 0's. They relate the two frames only where robot 0
// ties them to its own (its poses sight them, a prior): before, they always counted, and a
// robot that introduced two of another robot's landmarks kept the frames "joined" with
// nothing fixing the transform between them.
TEST(FrameGroups, ALandmarkCountsOnlyWhereItsOwnerTiesIt) {
  const std::map<FactorId, InterEdge> edges = {{1, sighting(1, 0, 5)}, {2, sighting(1, 0, 6)}};
  EXPECT_NE(frameGroupsOf(edges, noneTied).at(1), 0u);
  EXPECT_NE(frameGroupsOf(edges, [](Key l) { return l == landmarkKey(5, 0); }).at(1), 0u);
  EXPECT_EQ(frameGroupsOf(edges, allTied).at(1), 0u);
}

// A landmark robot 0 does not tie is fixed in its group all the same when robot 2, joined to
// robot 0 by a closure, sights it.
TEST(FrameGroups, ALandmarkSightedInItsOwnersGroupCounts) {
  std::map<FactorId, InterEdge> edges = {
      {1, sighting(1, 0, 5)}, {2, sighting(1, 0, 6)}, {3, sighting(2, 0, 5)}};
  EXPECT_NE(frameGroupsOf(edges, noneTied).at(1), 0u);  // 2 is in no group with 0 yet
  edges[4] = between(0, 2);
  EXPECT_NE(frameGroupsOf(edges, noneTied).at(1), 0u);  // one shared point: rotation free
  edges[5] = sighting(2, 0, 6);
  const auto g = frameGroupsOf(edges, noneTied);
  EXPECT_EQ(g.at(1), 0u);
  EXPECT_EQ(g.at(2), 0u);
}

// Points shared with a group count together whichever of its robots owns or sights them, and a
// join by points can enable the next one.
TEST(FrameGroups, PointsCountPerGroupAndJoinsChain) {
  // 0 and 2 share a frame; robot 1 sights one landmark of each.
  std::map<FactorId, InterEdge> edges = {
      {1, between(0, 2)}, {2, sighting(1, 0, 5)}, {3, sighting(1, 2, 7)}};
  EXPECT_EQ(frameGroupsOf(edges, allTied).at(1), 0u);
  // Robot 3 sights two of robot 1's landmarks, which robot 1 ties: it joins once 1 has joined.
  edges[4] = sighting(3, 1, 8);
  edges[5] = sighting(3, 1, 9);
  EXPECT_EQ(frameGroupsOf(edges, allTied).at(3), 0u);
  edges.erase(3);
  const auto g = frameGroupsOf(edges, allTied);
  EXPECT_NE(g.at(1), 0u);
  EXPECT_EQ(g.at(3), g.at(1));
}
