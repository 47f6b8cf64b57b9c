// Which robots share a frame (server/frame_groups.h): a between factor joins on its own,
// sightings once they name enough distinct landmarks.
#include "server/frame_groups.h"

#include <gtest/gtest.h>

using namespace loopd;
using namespace loopd::server;

namespace {

InterEdge between(std::uint32_t r, std::uint32_t s) { return {r, s, 0, 0}; }
InterEdge sighting(std::uint32_t r, std::uint32_t s, std::uint64_t landmark, int needed = 2) {
  return {r, s, landmarkKey(landmark, s), needed};
}

}  // namespace

TEST(FrameGroups, ABetweenFactorJoinsOnItsOwn) {
  const auto g = frameGroupsOf({{1, between(2, 1)}, {2, between(3, 4)}});
  EXPECT_EQ(g.at(1), 1u);
  EXPECT_EQ(g.at(2), 1u);
  EXPECT_EQ(g.at(3), 3u);
  EXPECT_EQ(g.at(4), 3u);
}

TEST(FrameGroups, SightingsJoinOnceTheyNameEnoughDistinctLandmarks) {
  std::map<FactorId, InterEdge> edges = {{1, sighting(0, 1, 5)}, {2, sighting(0, 1, 5)}};
  EXPECT_NE(frameGroupsOf(edges).at(1), 0u);  // one landmark, twice: the rotation is free
  edges[3] = sighting(1, 0, 9);               // the other way round counts for the same pair
  EXPECT_EQ(frameGroupsOf(edges).at(1), 0u);
  // 3D: three landmarks.
  std::map<FactorId, InterEdge> e3 = {{1, sighting(2, 3, 1, 3)}, {2, sighting(2, 3, 2, 3)}};
  EXPECT_NE(frameGroupsOf(e3).at(3), 2u);
  e3[3] = sighting(2, 3, 3, 3);
  EXPECT_EQ(frameGroupsOf(e3).at(3), 2u);
}

TEST(FrameGroups, ExtraJoinsAndChains) {
  const auto g = frameGroupsOf({{1, between(0, 1)}}, {{1, 2}, {3, 2}});
  for (std::uint32_t r = 0; r <= 3; ++r) EXPECT_EQ(g.at(r), 0u) << r;
}
